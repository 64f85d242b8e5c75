"""What the results MCAP of an analysis shows (``analyze --mcap-out``); :mod:`mrftcli.io.overlay` writes it."""

from __future__ import annotations

from typing import Any

from ..errors import InputError
from .record import AnalysisResult

__all__ = ["analysis_overlay"]


def analysis_overlay(result: AnalysisResult[Any, Any, Any]) -> dict[str, Any]:
    """What the results MCAP of an analysis shows, as the keyword arguments of
    :func:`mrftcli.io.overlay.write_overlay`: its tests (:attr:`AnalysisResult.segmented`), the
    identified model's prediction over each test (:func:`mrftcli.mrft.waveform.predict_tests`, driven
    by the recorded command), the parameters (every family's by name, in their units), metadata strings
    and the analysis itself (``result.to_json()``, attached to the MCAP as ``analysis.json``).

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
    segmented = result.segmented
    try:
        preds = predict_tests(result.model, segmented, flight.command.t, flight.command.values,
                              flight.output.t, flight.output.values)
        predicted = "the identified model driven by the recorded command"
    except InputError as err:  # the cascade's sampled inner loop: no continuous prediction
        preds, predicted = {}, f"none ({err})"
    tests = [OverlayTest(number=t.index + 1, t_start=t.t_start, t_end=t.t_end, beta=t.beta_effective,
                         beta_nominal=t.beta_nominal, h=t.h, bias=t.bias, frequency_hz=t.frequency_hz_mean,
                         amplitude=t.amplitude_mean, cycles=t.n_stable,
                         rms_residual=preds[t.index].rms if t.index in preds else float("nan"))
             for t in segmented]
    fits = [OverlayFit(number=i + 1, t=p.t, output=p.y + p.residual, predicted=p.y) for i, p in preds.items()]
    params = result.parameters_json()
    meta = {"log": str(result.path), "loop": result.loop, "model": result.model.family, "prediction": predicted,
            "mrft_ident_version": __version__,
            "time_base": "the original log's time [s] (MCAP log_time = seconds * 1e9)"}
    return {"tests": tests, "fits": fits, "parameters": params, "metadata": meta,
            "analysis_json": result.to_json()}
