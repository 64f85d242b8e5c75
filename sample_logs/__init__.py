"""The shipped sample logs; a few are installed with the package as ``mrftcli._samples`` (see
:func:`mrftcli.samples.sample_log`), so the API's examples run from any install."""
