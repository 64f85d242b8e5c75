"""What the results MCAP of an analysis shows (``analyze --mcap-out``); :mod:`mrftcli.io.overlay` writes it.

:func:`analysis_predictions` is the identified model's output over each test, driven by the recorded
command, which the overlay and the report's fit figure both draw.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from .record import AnalysisResult

__all__ = ["analysis_overlay", "analysis_predictions"]

#: command before each test that drives its first outputs [s] (covers any delay up to 1 s)
_HISTORY = 1.0


def analysis_predictions(result: AnalysisResult) -> dict[int, Any]:
    """The identified model's output over each of the record's tests (:attr:`AnalysisResult.segmented`),
    driven by the recorded command: ``MrftTest.index`` -> :class:`~mrftcli.mrft.waveform.PredictedOutput`.

    A continuous model through :func:`mrftcli.mrft.waveform.predict_tests`; the cascade, whose inner
    loop is sampled, through its exact discrete realisation at the outer relay's rate
    (:func:`_predict_sampled`). Initial state and trim are fitted per test in both.

    Raises
    ------
    InputError
        The result carries no flight signals.
    """
    from ..mrft.waveform import predict_tests

    flight = result.flight
    if flight is None:
        raise InputError("the analysis carries no flight signals to predict")
    signals = (flight.command.t, flight.command.values, flight.output.t, flight.output.values)
    if result.kind == "cascade":
        return _predict_sampled(result, *signals)
    return predict_tests(result.model, result.segmented, *signals, history=_HISTORY)


def _predict_sampled(result: AnalysisResult, tc: np.ndarray, u: np.ndarray, ty: np.ndarray,
                     y: np.ndarray) -> dict[int, Any]:
    """The cascade's output over each test: x_{k+1} = Phi x_k + Gamma (u_k - bias + offset), y_k = C x_k on the
    logged command's ticks, the tick outputs interpolated to the output times; the initial state and
    the trim offset by linear least squares on the recorded output (as the continuous prediction)."""
    from ..mrft.waveform import PredictedOutput

    d = result.model.discrete_realisation(result.controller_rate_hz)
    out = {}
    for test in result.segmented:
        a = int(np.searchsorted(tc, test.t_start - _HISTORY - 1e-9, side="left"))
        b = min(int(np.searchsorted(tc, test.t_end, side="left")) + 1, tc.size)
        ya, yb = np.searchsorted(ty, [test.t_start, test.t_end], side="left")
        if b - a < 2 or yb - ya < 8:
            continue
        ticks, drive = tc[a:b], u[a:b] - test.bias
        # columns: the response to the recorded command, to a unit trim, and to each initial state
        cols = np.zeros((ticks.size, 2 + d.order))
        x, x_trim, free = np.zeros(d.order), np.zeros(d.order), np.eye(d.order)
        for k in range(ticks.size):
            cols[k] = [d.C @ x, d.C @ x_trim, *(d.C @ free)]
            x, x_trim, free = d.Phi @ x + d.Gamma * drive[k], d.Phi @ x_trim + d.Gamma, d.Phi @ free
        at = np.column_stack([np.interp(ty[ya:yb], ticks, c) for c in cols.T])
        rec = y[ya:yb]
        coef, *_ = np.linalg.lstsq(at[:, 1:], rec - at[:, 0], rcond=None)
        pred = at[:, 0] + at[:, 1:] @ coef
        resid = rec - pred
        out[test.index] = PredictedOutput(t=ty[ya:yb], y=pred, residual=resid, x0=np.asarray(coef[1:], float),
                                          input_offset=float(coef[0]), rms=float(np.sqrt(np.mean(resid ** 2))))
    return out


def analysis_overlay(result: AnalysisResult) -> dict[str, Any]:
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

    if result.flight is None:
        raise InputError("the analysis carries no flight signals to overlay")
    segmented = result.segmented
    preds = analysis_predictions(result)
    tests = [OverlayTest(number=t.index + 1, t_start=t.t_start, t_end=t.t_end, beta=t.beta_effective,
                         beta_nominal=t.beta_nominal, h=t.h, bias=t.bias, frequency_hz=t.frequency_hz_mean,
                         amplitude=t.amplitude_mean, cycles=t.n_stable,
                         rms_residual=preds[t.index].rms if t.index in preds else float("nan"))
             for t in segmented]
    fits = [OverlayFit(number=i + 1, t=p.t, output=p.y + p.residual, predicted=p.y) for i, p in preds.items()]
    params = result.parameters_json()
    meta = {"log": str(result.path), "loop": result.loop, "model": result.model.family, "mrft_ident_version": __version__,
            "time_base": "the original log's time [s] (MCAP log_time = seconds * 1e9)"}
    return {"tests": tests, "fits": fits, "parameters": params, "metadata": meta,
            "analysis_json": result.to_json()}
