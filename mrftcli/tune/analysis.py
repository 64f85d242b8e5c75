"""Tune an analysed log: its posterior, its controller rate, and the flat figures ``batch --tune`` stores.

The controller rate is the one the analysis records (``AnalysisResult.controller_rate_hz``), the same
whether the log or its RESULT.json is tuned (:func:`mrftcli.analyze.analysis_controller_rate`).

Where the posterior comes from:

* an :class:`~mrftcli.analyze.AnalysisResult` (a LOG): with the MRFT estimate, its bootstrap over
  stable cycles (joint draws, so the Td-tau-K correlation is kept); with the waveform refinement
  accepted (``method == "waveform"``), multivariate normal draws from the refinement's Gauss-Newton
  covariance of (ln Td, tau, K), which is the estimate's own uncertainty (the MRFT bootstrap is
  centred elsewhere and wider), again with the correlation;
* an analyze RESULT.json (its ``parameters``): the JSON holds means, standard deviations and
  intervals but no draws and no covariance (neither ``parameters``, ``parameters_mrft`` nor
  ``refinement`` carries one), so the draws are independent log-normal ones and the result says so;
* spreads given by hand (:meth:`Posterior.from_spread`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..analyze import AnalysisResult
from ..errors import InputError
from ..mrft.model import LoopModel
from .design import DesignOptions, Posterior, TuneResult, tune

__all__ = ["posterior_from_analysis", "model_from_result_json", "tune_analysis",
           "summary_figures", "recommended_design_name", "NO_CORRELATION_NOTE", "SUMMARY_FIGURES", "ASSUMED_RATE_HZ",
           "RATE_ASSUMED_NOTE"]

#: Controller rate [Hz] :func:`tune_analysis` assumes when neither the caller nor the analysis gives one.
ASSUMED_RATE_HZ = 200.0

#: The note a result tuned at :data:`ASSUMED_RATE_HZ` carries first.
RATE_ASSUMED_NOTE = (f"assumption: controller rate {ASSUMED_RATE_HZ:g} Hz (the log records none; give the rate "
                     "to tune for your controller)")

#: The figures :func:`summary_figures` gives (the ``tune_*`` columns of the batch summary).
SUMMARY_FIGURES = ("tune_design", "tune_kind", "tune_Kp", "tune_Ki", "tune_Kd", "tune_Tf", "tune_rate_hz",
                   "tune_pm_deg", "tune_pm_worst_deg", "tune_dm_ms", "tune_ms", "tune_ms_worst",
                   "tune_overshoot_pct", "tune_settling_s", "tune_error")

#: Said whenever the posterior had to be built without the parameters' correlation.
NO_CORRELATION_NOTE = ("the RESULT.json holds no draws or covariance, so Td, tau and K are drawn independently "
                       "from their reported std: the Td-tau correlation is lost and the robust design is more "
                       "cautious than from the log itself (tune the LOG to keep it)")


def posterior_from_analysis(result: AnalysisResult, n: int = 400, seed: int = 0) -> Posterior:
    """The posterior of an analysed log (module docstring): bootstrap draws, or the refinement's covariance.

    Parameters
    ----------
    result : AnalysisResult
    n : int
        Draws from the refinement's covariance (the bootstrap's own draws are used as they are).
    seed : int
        Seed of those draws.
    """
    ref = result.refinement
    if result.method == "waveform" and ref is not None and np.all(np.isfinite(ref.fit.covariance)):
        rng = np.random.default_rng(seed)
        cov = np.asarray(ref.fit.covariance, float)
        p = rng.multivariate_normal(np.asarray(ref.fit.p, float), cov, size=n, method="eigh")
        sign = -1.0 if result.K.value * ref.fit.p[2] < 0 else 1.0  # the fit's K carries the loop sign
        return Posterior(result.model, np.exp(p[:, 0]), p[:, 1], sign * p[:, 2],  # a lead held at 0 there
                         source="waveform refinement: normal draws from its Gauss-Newton covariance of "
                                "(ln Td, tau, K), correlation kept")
    b = result.bootstrap
    # the draws alone: the analysis keeps the bootstrap's rows 1.. (row 0, the estimate on the data themselves, is
    # the point estimate; mrftcli.analyze.estimate.Consensus.draws)
    Td, tau, K = (np.asarray(b.get(k, []), float) for k in ("Td", "tau", "K"))
    return Posterior(result.model, Td, tau, K, source="analyze bootstrap over stable cycles (joint draws)")


def model_from_result_json(data: Mapping[str, Any] | AnalysisResult, known: LoopModel, n: int = 200,
                           seed: int = 0) -> tuple[LoopModel, Posterior, str]:
    """(model, posterior, note) from an ``analyze --json`` object, read by :meth:`AnalysisResult.from_json`.

    ``known`` is eq. (2) with the bench test's Tp (``soiptd_model(Tp)``): the result must have been
    identified with it. The model is the reported estimate (``parameters`` Td, tau, K); the posterior is independent
    log-normal draws from the reported std (:data:`NO_CORRELATION_NOTE`, returned as the note to
    show). A std the JSON leaves out (null: not determined) counts as 0.

    Raises
    ------
    InputError
        Not an analyze result, or analysed with another Tp.
    """
    result = data if isinstance(data, AnalysisResult) else AnalysisResult.from_json(data)
    Tp = known.Tp
    if abs(result.Tp - Tp) > 1e-9 * Tp:
        raise InputError(f"--tp {Tp} differs from the Tp {result.Tp} the RESULT.json was identified with")
    est = {k: (e.value, e.std if np.isfinite(e.std) else 0.0)
           for k, e in (("Td", result.Td), ("tau", result.tau), ("K", result.K))}
    model = known.with_parameters(Td=est["Td"][0], tau=est["tau"][0], K=est["K"][0])
    post = Posterior.from_spread(model, est["Td"][1], est["tau"][1], est["K"][1], n=n, seed=seed,
                                 source="RESULT.json: independent log-normal draws from the reported std")
    return model, post, NO_CORRELATION_NOTE


def tune_analysis(result: AnalysisResult, *, kinds=("PD",), rate_hz: float | None = None,
                  designs=("mrft-rule", "model-based", "robust"), **options) -> TuneResult:
    """:func:`~mrftcli.tune.design.tune` on an analysed log: its model, its posterior, its controller rate.

    ``rate_hz`` defaults to the controller rate the analysis records (``result.controller_rate_hz``;
    :data:`ASSUMED_RATE_HZ` when it has none, and the result's first note says so); ``options`` go to
    its :class:`~mrftcli.tune.design.DesignOptions` (``objective``, ``ms_max``, ``effort_max``) and ``progress``.
    """
    rate = rate_hz if rate_hz is not None else result.controller_rate_hz
    progress = options.pop("progress", None)
    res = tune(result.model, rate or ASSUMED_RATE_HZ, posterior=posterior_from_analysis(result),
               options=DesignOptions(kinds=kinds, designs=designs, **options), loop=result.loop, progress=progress)
    if not rate:
        # stated with the gains (their notes reach the table, the JSON and the report): never a silent default
        res = dataclasses.replace(res, notes=(RATE_ASSUMED_NOTE, *res.notes))
    return res


def recommended_design_name(res: TuneResult, kind: str | None = None) -> str:
    """The design recommended when none is asked for (tune's export, its report, vehicle, the summary figures):
    ``robust`` when the identification gave a posterior (a robust design of ``kind``; of any kind when None),
    else ``model-based``."""
    return "robust" if any(d.name == "robust" and kind in (None, d.kind) for d in res.designs) else "model-based"


def summary_figures(res: TuneResult, kind: str = "PD") -> dict[str, Any]:
    """One design's gains and figures as flat ``tune_*`` values (:data:`SUMMARY_FIGURES`).

    The design is the robust one when there is a posterior, else the model-based one (as the
    CLI's export). Margins: nominal phase margin [deg], worst over the posterior's 95 % set, exact
    delay margin [ms], Ms (nominal and worst); step: overshoot [%] and 2 % settling time [s].
    """
    name = recommended_design_name(res, kind)
    d = res.get(name, kind)
    c, w = d.controller, (d.posterior.get("worst", {}) if d.posterior else {})
    return {"tune_design": name, "tune_kind": kind, "tune_Kp": c.Kp, "tune_Ki": c.Ki, "tune_Kd": c.Kd,
            "tune_Tf": c.Tf, "tune_rate_hz": c.rate_hz, "tune_pm_deg": d.margins.phase_margin_deg,
            "tune_pm_worst_deg": w.get("phase_margin_deg", float("nan")),
            "tune_dm_ms": d.margins.delay_margin_s * 1e3, "tune_ms": d.margins.Ms,
            "tune_ms_worst": w.get("Ms", float("nan")), "tune_overshoot_pct": d.step.overshoot_pct,
            "tune_settling_s": d.step.settling_s, "tune_error": None}
