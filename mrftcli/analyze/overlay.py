"""What the results MCAP of an analysis shows (``analyze --mcap-out``); :mod:`mrftcli.io.overlay` writes it."""

from __future__ import annotations

from typing import Any

from ..errors import InputError
from ..mrft.parameter import ParameterEstimate
from .record import AnalysisResult

__all__ = ["analysis_overlay"]


def analysis_overlay(result: AnalysisResult) -> dict[str, Any]:
    """What the results MCAP of an analysis shows, as the keyword arguments of
    :func:`mrftcli.io.overlay.write_overlay`: its tests, the identified model's prediction over each
    test (:func:`mrftcli.mrft.waveform.predict_tests`, driven by the recorded command), the
    parameters [s; K in output units / (command unit s^2)], metadata strings and the analysis itself
    (``result.to_json()``, attached to the MCAP as ``analysis.json``).

    Raises
    ------
    InputError
        The result carries no flight signals (``result.flight`` is None).
    """
    from .._version import __version__
    from ..io.overlay import OverlayFit, OverlayTest
    from ..mrft.waveform import predict_tests

    flight = result.flight
    if flight is None:
        raise InputError("the analysis carries no flight signals to overlay")
    preds = predict_tests(result.model, result.tests, flight.command.t, flight.command.values,
                          flight.output.t, flight.output.values)
    tests = [OverlayTest(number=t.index + 1, t_start=t.t_start, t_end=t.t_end, beta=t.beta_effective,
                         beta_nominal=t.beta_nominal, h=t.h, bias=t.bias, frequency_hz=t.frequency_hz_mean,
                         amplitude=t.amplitude_mean, cycles=t.n_stable,
                         rms_residual=preds[t.index].rms if t.index in preds else float("nan"))
             for t in result.tests]
    fits = [OverlayFit(number=i + 1, t=p.t, output=p.y + p.residual, predicted=p.y) for i, p in preds.items()]
    params = {name: est.to_json() for name, est in (("Tp", ParameterEstimate.given(result.Tp, "s")), ("Td", result.Td),
                                                    ("tau", result.tau), ("K", result.K))}
    meta = {"log": str(result.path), "loop": result.loop, "mrft_ident_version": __version__,
            "time_base": "the original log's time [s] (MCAP log_time = seconds * 1e9)"}
    return {"tests": tests, "fits": fits, "parameters": params, "metadata": meta,
            "analysis_json": result.to_json()}
