"""mrft-ident: identify multirotor loop models from MRFT flight logs.

The pipeline mirrors the packages: :mod:`mrftcli.io` (read a log) -> :mod:`mrftcli.segment` (find the
tests and their stable cycles) -> :mod:`mrftcli.mrft` (model, exact limit cycle, UFM, identification,
consensus) -> :mod:`mrftcli.analyze` (the one-log use case) -> :mod:`mrftcli.diagnose` ->
:mod:`mrftcli.report`; :mod:`mrftcli.cli` is a thin click layer on top.

The Python API a notebook needs is here (imported lazily, so ``mrft-ident --help`` stays fast):

=====================  ==========================================================================
:func:`read_flight`    one loop's signals from a log (:func:`mrftcli.io.read_flight`)
:func:`analyze_flight` segment a flight's MRFT tests and identify Td, tau, K with uncertainty
:func:`analyze_path`   read a log and analyse it (:mod:`mrftcli.analyze`)
:class:`ReadOptions`   how to read a loop from a log (topics, scales, layout, format, time unit)
:class:`AnalyzeOptions` the analysis's knobs (min cycles, bootstrap draws, seed, constraints, ...)
:func:`diagnose_flight` where the identified model and the recording disagree
                       (:func:`mrftcli.diagnose.diagnose`; the name ``diagnose`` is the subpackage's)
:func:`predict`        the exact MRFT limit cycle of a model (:func:`mrftcli.mrft.lprs.mrft_limit_cycle`)
:func:`identify`       any family's unknown parameters from its tests (:func:`mrftcli.mrft.identify.identify`)
:class:`TestMeasurement`  one measured MRFT test for :func:`identify` (eq. (2), the cascade)
:class:`ResponsePoint`  one measured point of G(j omega) for :func:`identify` (the process families)
:class:`LoopModel`     the paper's model, eq. (2)
:func:`family_model`   a process family to identify (known parameters, ranges)
:func:`sample_log`     a sample log installed with the package (for the examples)
=====================  ==========================================================================

Examples
--------
Predict the limit cycle of the paper's example plant, then identify it back from the two tests:

>>> import mrftcli
>>> plant = mrftcli.LoopModel(Tp=0.1, Td=0.7042, tau=0.06)
>>> cycles = {beta: mrftcli.predict(plant, beta) for beta in (-0.4, -0.7)}
>>> round(cycles[-0.4].frequency_hz, 5), round(cycles[-0.7].frequency_hz, 5)
(0.70565, 1.01885)
>>> tests = [mrftcli.TestMeasurement(beta, c.frequency_hz) for beta, c in cycles.items()]
>>> result = mrftcli.identify(tests, mrftcli.soiptd_model(0.1))  # eq. (2) with Tp known
>>> print(f"Td {result.Td.value:.4f} s, tau {result.tau.value:.4f} s")
Td 0.7042 s, tau 0.0600 s

Analyse a shipped sample log (a simulated Design I altitude flight: Td 2.669 s, tau 46.4 ms, K 19.62):

>>> log = mrftcli.sample_log("design1_altitude.mcap")  # installed with the package
>>> flight = mrftcli.read_flight(log, mrftcli.ReadOptions(loop="altitude"))
>>> analysis = mrftcli.analyze_flight(flight, mrftcli.soiptd_model(0.0422),
...                                  options=mrftcli.AnalyzeOptions(n_bootstrap=100))
>>> print(f"{len(analysis.tests)} tests: Td {analysis.Td.value:.1f} s, tau {analysis.tau.value * 1e3:.0f} ms, "
...       f"K {analysis.K.value:.0f}")
2 tests: Td 2.7 s, tau 46 ms, K 20
>>> diagnosis = mrftcli.diagnose_flight(flight, mrftcli.soiptd_model(0.0422), analysis=analysis)  # doctest: +SKIP
"""

from __future__ import annotations

from importlib import import_module as _import_module
from typing import TYPE_CHECKING

from ._version import __version__

#: public name -> (module, attribute), imported on first use (PEP 562)
_LAZY = {
    "read_flight": ("mrftcli.io", "read_flight"),
    "ReadOptions": ("mrftcli.io", "ReadOptions"),
    "analyze_flight": ("mrftcli.analyze", "analyze_flight"),
    "analyze_path": ("mrftcli.analyze", "analyze_path"),
    "AnalyzeOptions": ("mrftcli.analyze", "AnalyzeOptions"),
    "diagnose_flight": ("mrftcli.diagnose", "diagnose"),
    "predict": ("mrftcli.mrft.lprs", "mrft_limit_cycle"),
    "identify": ("mrftcli.mrft.identify", "identify"),
    "TestMeasurement": ("mrftcli.mrft.identify", "TestMeasurement"),
    "ResponsePoint": ("mrftcli.mrft.identify", "ResponsePoint"),
    "family_model": ("mrftcli.mrft.families", "family_model"),
    "LoopModel": ("mrftcli.mrft.model", "LoopModel"),
    "soiptd_model": ("mrftcli.mrft.model", "soiptd_model"),
    "sample_log": ("mrftcli.samples", "sample_log"),
}

__all__ = ["__version__", *_LAZY]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names load on first use
    from .analyze import AnalyzeOptions, analyze_flight, analyze_path
    from .diagnose import diagnose as diagnose_flight
    from .io import ReadOptions, read_flight
    from .mrft.families import family_model
    from .mrft.identify import ResponsePoint, TestMeasurement, identify
    from .mrft.lprs import mrft_limit_cycle as predict
    from .mrft.model import LoopModel
    from .samples import sample_log


def __getattr__(name: str) -> object:
    try:
        module, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'mrftcli' has no attribute {name!r}") from None
    value = getattr(_import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
