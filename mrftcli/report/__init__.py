"""HTML + PNG reports; the only part of mrftcli that imports matplotlib (Agg backend).

Compute first, plot second: every plotting function takes a finished result object
(:class:`~mrftcli.analyze.AnalysisResult`, ...) and draws it; nothing here computes an estimate.

* :mod:`mrftcli.report.analysis` - ``mrft-ident analyze --report DIR``
* :mod:`mrftcli.report.diagnosis` - ``mrft-ident analyze --diagnose --report DIR`` / ``diagnose``
* :mod:`mrftcli.report.fleet` - ``mrft-ident batch``
* :mod:`mrftcli.report._common` - page template and figure helpers shared by the three
"""
