"""Where a model and the recording disagree, for every family: which test, which feature, which cycles,
which harmonic.

Eq. (2) (its cycles compared feature by feature, :mod:`.candidates`): :func:`locate` lists the
features beyond :data:`Z_LIMIT` standard errors (and the period scatter beyond what noise explains),
the harmonics whose G(j k Omega) is off by more than 5 %, and the runs of cycles whose waveform error
stands out; :func:`unexplained_mismatch` describes what no candidate explains.

Every other family: the waveform checks, test by test. The driver
(:func:`mrftcli.diagnose.selection.diagnose`) runs these stages after the analysis:

1. the analysis (:func:`mrftcli.analyze.general.general_analysis`): the tests, their relays, the model
   identified from all tests and each test's held-out cycle (from the model of the other tests);
2. the measured waveform (:func:`measured_waveform`): each test's stable cycles as harmonics of their
   period, averaged in the cycle's phase (the noise averages out), with the standard error of each
   harmonic from the cycle-to-cycle scatter;
3. the check per test (:func:`check_test`): the exact limit cycle (LPRS, sampled at the controller's
   rate) of the model from the OTHER tests and of the model from all tests under the test's relay;
   frequency and amplitude errors against their scatter (the measurement's standard error, the
   held-out model's parameter spread and the sampled relay's band of orbits), the waveform residual
   by harmonic band (fundamental, 2-3, higher) against the noise (:func:`test_disagreements`);
4. the library of physics (:mod:`.physics`): each effect fitted and held out, named only when it
   improves the held-out prediction;
5. the verdict (:func:`verdict`): the effects found, or consistent, or unexplained with where the
   residual sits.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from scipy.stats import chi2 as chi2_dist, norm

from ..analyze.general import MeasuredTest, TestSummary, identify_points
from ..analyze.smooth_cycle import cycle_harmonics, peak_amplitude, predicted_cycle
from ..errors import IdentificationError, InputError
from ..mrft.identify_lti import LtiIdentification, ResponsePoint
from ..mrft.lprs import LimitCycle
from ..mrft.model import PlantModel
from .features import FEATURE_NAMES
from .fit import Fit, feature_mask
from .prepared import DiagnosedTest
from .candidate_model import CandidateModel
from .heldout import harmonic_errors, held_out_p, waveform_errors
from ..jsonable import finite_or_none, json_opt_float
from .physics import Z_LIMIT
from .records import CandidateFit, CycleErrors, Disagreement, EffectFinding, FinalModel, HeldOut, Unexplained
from .scatter import scatter_z

if TYPE_CHECKING:
    from .physics import EffectFit

__all__ = ["UNEXPLAINED_P", "FEATURE_TEXT", "Located", "locate", "unexplained_mismatch", "TestCheck", "BandResidual",
           "MeasuredWaveform", "measured_waveform", "check_test", "test_disagreements", "misfit", "verdict", "Z_LIMIT"]

#: a mismatch counts as unexplained below this chi^2 p-value (fitting and held-out cycles of the linear
#: model, and the held-out cycles of the model finally chosen)
UNEXPLAINED_P = 1e-3

#: each feature in words
FEATURE_TEXT = {
    "period": "oscillation period",
    "balance": "half-period balance (time at +h vs -h)",
    "log_amplitude": "amplitude",
    "centre": "oscillation centre relative to the setpoint",
    "h3_re": "3rd-harmonic content of the waveform",
    "h3_im": "3rd-harmonic content of the waveform",
    "h5_re": "5th-harmonic content of the waveform",
    "h5_im": "5th-harmonic content of the waveform",
    "h2_re": "2nd-harmonic content of the waveform (the two half-cycles differ)",
    "h2_im": "2nd-harmonic content of the waveform (the two half-cycles differ)",
    "amplitude_trend": "amplitude trend over time",
    "balance_trend": "half-period balance trend over time",
    "period_scatter": "cycle-to-cycle period scatter",
}


@dataclass(frozen=True)
class Located:
    """Where a model disagrees with the recording (:func:`locate`).

    Attributes
    ----------
    items : list of Disagreement
        The disagreements, largest first: ``kind`` "feature" (z beyond 3), "harmonic" (G(j k Omega)
        off by more than 5 %) or "segment" (a run of cycles whose waveform error stands out); empty
        when no feature disagrees beyond the noise.
    cycle_errors : list of CycleErrors
        Per test, every cycle's waveform NRMSE (the report's plot).
    harmonics : list of dict
        Per test, the relative error of G(j k Omega) per odd harmonic k.
    """

    items: list[Disagreement]
    cycle_errors: list[CycleErrors]
    harmonics: list[dict[str, Any]]


def _at(t: DiagnosedTest) -> dict[str, Any]:
    """Where a disagreement of test ``t`` is: the test, its mean beta, relay height and span [s]."""
    return {"test": t.index, "beta": float(np.mean(t.beta)), "h": t.h, "t_start": t.t_start, "t_end": t.t_end}


def _feature_items(t: DiagnosedTest, values: np.ndarray, fm: np.ndarray, z: np.ndarray) -> list[Disagreement]:
    """The features of test ``t`` beyond :data:`Z_LIMIT` standard errors, recorded (``values``) against model (``fm``)."""
    ia = FEATURE_NAMES.index("log_amplitude")
    out = []
    for j, name in enumerate(FEATURE_NAMES):
        if not feature_mask(t)[j] or abs(z[j]) < Z_LIMIT:
            continue
        rec, mod = float(values[j]), float(fm[j])
        item: dict[str, Any] = {"kind": "feature", **_at(t), "feature": name, "what": FEATURE_TEXT[name],
                                "recorded": rec, "model": mod, "difference": rec - mod, "z": float(z[j])}
        if name == "log_amplitude":
            item.update(recorded=math.exp(rec), model=math.exp(mod), difference=math.exp(rec) - math.exp(mod),
                        relative=math.exp(rec - mod) - 1.0)
        if name == "period":
            item["relative"] = rec / mod - 1.0
            item["unit"] = "s"
        if name == "centre":
            a_rec = math.exp(float(values[ia]))
            item.update(recorded=rec * a_rec, model=mod * math.exp(float(fm[ia])),
                        difference=rec * a_rec - mod * math.exp(float(fm[ia])), unit="output units")
        if name in ("amplitude_trend", "balance_trend"):
            item["unit"] = "relative change per second" if name == "amplitude_trend" else "per second"
        if name == "balance":
            P = float(values[0])
            item["half_periods_recorded"] = {"high": P * (0.5 + rec), "low": P * (0.5 - rec)}
            item["half_periods_model"] = {"high": P * (0.5 + mod), "low": P * (0.5 - mod)}
        out.append(Disagreement(**item))
    return out


def _scatter_item(t: DiagnosedTest, sc: dict[str, Any]) -> Disagreement | None:
    """The period scatter of test ``t`` when it is beyond :data:`Z_LIMIT` standard errors of what noise explains."""
    zs = float(scatter_z([t], [sc], "all", [sc["v0"]])[0])
    if not abs(zs) >= Z_LIMIT:
        return None
    s_rec = math.sqrt(t.scatter_var("all")[0])
    return Disagreement("feature", **_at(t), feature="period_scatter",
                        what=FEATURE_TEXT["period_scatter"], recorded=s_rec, model=sc["s0"],
                        difference=s_rec - sc["s0"], z=zs)


def _harmonic_item(t: DiagnosedTest, harm: dict[str, Any]) -> Disagreement | None:
    """The worse of the fundamental and the 3rd harmonic when its G(j k Omega) is off by more than 5 %
    (only these two are well above the noise at realistic amplitudes)."""
    strong = {k: v for k, v in harm.items() if k in ("1", "3")}
    if not strong:
        return None
    kmax = max(strong, key=lambda k: strong[k])
    if not strong[kmax] > 0.05:
        return None
    return Disagreement("harmonic", **_at(t), harmonic=int(kmax),
                        what=f"G(j{kmax}Omega) measured from harmonic {kmax} of output/command",
                        relative_error=harm[kmax], all=harm)


def _segment_items(tests: list[DiagnosedTest], cycle_errors: list[CycleErrors]) -> list[Disagreement]:
    """Runs of cycles whose waveform error stands out from the log's typical cycle."""
    out: list[Disagreement] = []
    if not cycle_errors:
        return out
    med = float(np.nanmedian(np.concatenate([ce.nrmse for ce in cycle_errors])))
    for t, ce in zip(tests, cycle_errors):
        bad = ce.nrmse > max(1.5 * med, 0.02)
        if not bad.any():
            continue
        idx = np.flatnonzero(bad)
        for rr in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            hi_err = float(np.nanmean(ce.hi[rr]))
            lo_err = float(np.nanmean(ce.lo[rr]))
            out.append(Disagreement(
                "segment", **{**_at(t), "t_start": float(ce.start[rr[0]]), "t_end": float(ce.end[rr[-1]])},
                cycles=[int(x) for x in rr],
                nrmse=float(np.nanmean(ce.nrmse[rr])),
                typical_nrmse=med,
                worse_half="high (+h)" if hi_err > lo_err else "low (-h)",
                half_nrmse={"high": hi_err, "low": lo_err},
            ))
    return out


def _rank(d: Disagreement) -> float:
    """Features first, largest |z| first, then the harmonics, then the segments."""
    if d.kind == "feature":
        return -abs(d.z if d.z is not None else 0.0)
    return 0 if d.kind == "harmonic" else 1


def locate(tests: list[DiagnosedTest], model: CandidateModel, fit: Fit, recs_all: list[Any], scatter: list[dict[str, Any]]) -> Located:
    """Where ``model`` (fitted: ``fit``) and the recording disagree: features, cycles/halves, harmonics.

    Parameters
    ----------
    tests : list of DiagnosedTest
        The tests diagnosed.
    model, fit : CandidateModel, Fit
        The model and its fit (the linear one, or with the effects chosen).
    recs_all : list of (FeatureSummary, ndarray)
        Per test, the features over all its stable cycles and their standard errors.
    scatter : list of dict
        Per test, the noise-only period scatter (:func:`mrftcli.diagnose.scatter.scatter_reference`).
    """
    items: list[Disagreement] = []
    ia = FEATURE_NAMES.index("log_amplitude")
    cycle_errors: list[CycleErrors] = []
    harmonics: list[dict[str, Any]] = []
    for i, (t, (feats, sigma)) in enumerate(zip(tests, recs_all)):
        ev = model.evaluate(fit.theta, i, feats.t_mean, key=4000 + i)
        if ev is None:
            continue
        fm = ev.features.copy()
        fm[ia] += math.log(fit.K)
        items += _feature_items(t, feats.values, fm, (feats.values - fm) / sigma)
        scatter_item = _scatter_item(t, scatter[i])
        if scatter_item is not None:
            items.append(scatter_item)
        # per cycle and half-cycle waveform errors
        allm = np.ones(len(t.tab), bool)
        e, v, e_hi, e_lo = waveform_errors(t, allm, [ev], fit.K)
        cycle_errors.append(CycleErrors(t=t.tab.t_mid, nrmse=np.sqrt(e / np.where(v > 0, v, np.nan)),
                                        hi=np.sqrt(e_hi / v), lo=np.sqrt(e_lo / v), start=t.tab.start, end=t.tab.end))
        harm = harmonic_errors(t, allm, ev, fit.K)
        harmonics.append(harm)
        harmonic_item = _harmonic_item(t, harm)
        if harmonic_item is not None:
            items.append(harmonic_item)
    # time segments only when some feature disagrees beyond the noise at all: otherwise they would flag noise
    if any(d.kind == "feature" for d in items):
        items += _segment_items(tests, cycle_errors)
    else:
        items = []
    items.sort(key=_rank)
    return Located(items=items, cycle_errors=cycle_errors, harmonics=harmonics)


def unexplained_mismatch(tests: list[DiagnosedTest], base: Fit, before: HeldOut, effects: list[EffectFinding],
                         final: FinalModel | None, cand_rows: list[CandidateFit], recs_all: list[Any], scatter: list[dict[str, Any]],
                         t0_log: float, base_located: list[Disagreement]) -> Unexplained | None:
    """The mismatch no candidate (or pair) explains: where and how large, or None.

    Reported when the linear model is rejected on the fitting cycles *and* on the held-out ones
    (chi^2 p-value below :data:`UNEXPLAINED_P` on both), and the model finally chosen (the linear one
    when nothing was found) is still rejected on the held-out cycles at that level.
    """
    dof_fit = max(base.n - base.k, 1)
    p_fit = float(chi2_dist.sf(base.chi2, dof_fit))
    p_hold = held_out_p(before, tests)
    if not (p_fit < UNEXPLAINED_P and p_hold < UNEXPLAINED_P):
        return None
    det = [e for e in effects if e.name != "delay_jitter"]
    held = det[-1].fit_after if det else before
    p_final = held_out_p(held, tests)
    if not p_final < UNEXPLAINED_P:
        return None
    model_name = "linear" if final is None else f"linear + {final.label}"
    # where: the base model's disagreements, or the chosen model's when an effect was modelled
    located = base_located if final is None else locate(tests, final.model, final.fit, recs_all, scatter).items
    feats = [d for d in located if d.kind == "feature"]
    segs = [d for d in located if d.kind == "segment"]
    harms = [d for d in located if d.kind == "harmonic"]
    worst = feats[0] if feats else None
    gains = [(r, r.delta_bic) for r in cand_rows if r.delta_bic is not None]
    tested = [(r, gain) for r, gain in sorted(gains, key=lambda rg: -rg[1])]
    where_tests = sorted({d.test + 1 for d in feats})
    half = None
    if segs:
        halves = [d.worse_half for d in segs]
        half = max(set(halves), key=halves.count)
    return Unexplained(
        after=model_name,
        what=("the linear model is rejected, and no candidate effect (or pair) of the library explains the "
              "mismatch" if final is None else
              f"the model with {final.label} still leaves a mismatch beyond the noise on the held-out cycles"),
        held_out_feature_chi2=held.feature_chi2,
        held_out_features=sum(int(feature_mask(t).sum()) for t in tests),
        p_value=p_final,
        held_out_nrmse_raw=held.nrmse_raw,
        tests=where_tests,
        largest=None if worst is None else {
            "test": worst.test + 1, "feature": worst.feature, "what": worst.what, "z": worst.z,
            "recorded": worst.recorded, "model": worst.model},
        segments=[{"test": d.test + 1, "t_start_rel": d.t_start - t0_log, "t_end_rel": d.t_end - t0_log,
                   "cycles": [c + 1 for c in d.cycles or []], "nrmse": d.nrmse, "worse_half": d.worse_half}
                  for d in segs[:5]],
        harmonics=[{"test": d.test + 1, "harmonic": d.harmonic, "relative_error": d.relative_error}
                   for d in harms[:5]],
        best_candidate=None if not tested else {"name": tested[0][0].name, "delta_bic": tested[0][1],
                                                "significant": bool(tested[0][0].significant)},
        worse_half=half,
    )


# ==================================================================================================
# every other family: the waveform checks, test by test
# ==================================================================================================
#: the harmonic bands the residual is reported in (fundamental; 2-3: even 2 shows an asymmetry; higher)
BANDS = (("fundamental", 1, 1), ("2-3", 2, 3), ("higher", 4, 8))
#: relative floor of a harmonic's standard error: a relay deciding on samples switches up to a
#: sample late, which moves the weak harmonics by 1-3 % from cycle to cycle (as
#: :func:`mrftcli.analyze.general.identify_points` floors the harmonics' points)
_HARMONIC_FLOOR = 0.03


# ----------------------------------------------------------------------------------------------
# records
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BandResidual:
    """The waveform residual of one harmonic band against a model's limit cycle.

    Attributes
    ----------
    band : str
        ``"fundamental"``, ``"2-3"`` or ``"higher"``.
    first, last : int
        The harmonics of the band (those measured).
    residual : float
        RMS over the band of |measured - model| per harmonic [output units].
    noise : float
        RMS over the band of the harmonics' standard error [output units] (the cycles' scatter over
        sqrt(n), floored at 3 % of the harmonic and at the sampled relay's timing, with the model's
        spread over the sampled relay's orbits, see ``_bands`` and ``_orbit_spread``).
    peak : int
        The harmonic of the band furthest above its noise.
    """

    band: str
    first: int
    last: int
    residual: float
    noise: float
    peak: int = 0

    @property
    def ratio(self) -> float:
        """Residual over noise [-]."""
        return self.residual / self.noise if self.noise > 0 else math.inf

    def describe(self) -> str:
        """E.g. ``harmonics 2-3``."""
        if self.last == 1:
            return "the fundamental"
        span = f"harmonic {self.first}" if self.first == self.last else f"harmonics {self.first}-{self.last}"
        return span + (f" (most at {self.peak})" if self.first < self.peak <= self.last or self.peak == self.last
                       and self.first < self.last else "")

    def to_json(self) -> dict[str, Any]:
        return {"band": self.band, "first": self.first, "last": self.last, "residual": self.residual,
                "noise": self.noise, "ratio": finite_or_none(self.ratio), "peak": self.peak}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> BandResidual:
        return cls(str(d["band"]), int(d["first"]), int(d["last"]), float(d["residual"]), float(d["noise"]),
                   int(d.get("peak", 0)))


@dataclass(frozen=True)
class TestCheck:
    """One test against the model of the other tests (held out) and of all tests.

    Attributes
    ----------
    index : int
        Test number (0-based, as the analysis).
    t_start, t_end : float
        Its span [s, log clock].
    frequency_hz, frequency_se_hz : float
        Measured mean frequency and its standard error [Hz].
    amplitude, amplitude_se : float
        The smooth (mean) waveform's amplitude and its standard error [output units].
    held_out_frequency_hz, held_out_amplitude : float or None
        The cycle of the model from the other tests [Hz], [output units]; None: not determined.
    held_out_frequency_sigma_hz, held_out_amplitude_sigma : float or None
        The difference's standard deviation: the measurement's error and the held-out model's
        parameter spread [Hz], [output units].
    all_frequency_hz, all_amplitude : float or None
        The cycle of the model from all tests [Hz], [output units].
    held_out_bands, all_bands : tuple of BandResidual
        The waveform residual by band against each model's limit cycle.
    even_ratio : float
        The measured even harmonics' RMS over their noise [-] (a symmetric relay on a linear plant
        gives none).
    note : str
        Why a figure is missing, or ``""``.
    """

    __test__ = False

    index: int
    t_start: float
    t_end: float
    frequency_hz: float
    frequency_se_hz: float
    amplitude: float
    amplitude_se: float
    held_out_frequency_hz: float | None
    held_out_amplitude: float | None
    held_out_frequency_sigma_hz: float | None
    held_out_amplitude_sigma: float | None
    all_frequency_hz: float | None
    all_amplitude: float | None
    held_out_bands: tuple[BandResidual, ...] = ()
    all_bands: tuple[BandResidual, ...] = ()
    even_ratio: float = 0.0
    note: str = ""

    @property
    def frequency_error(self) -> float | None:
        """(measured - held out) / held out [-]."""
        f = self.held_out_frequency_hz
        return None if f is None else self.frequency_hz / f - 1.0

    @property
    def frequency_z(self) -> float | None:
        """The held-out frequency difference over its standard deviation [-]."""
        f, s = self.held_out_frequency_hz, self.held_out_frequency_sigma_hz
        return None if f is None or s is None or not s > 0 else (self.frequency_hz - f) / s

    @property
    def amplitude_error(self) -> float | None:
        """(measured - held out) / held out [-]."""
        a = self.held_out_amplitude
        return None if a is None or a == 0 else self.amplitude / a - 1.0

    @property
    def amplitude_z(self) -> float | None:
        """The held-out amplitude difference over its standard deviation [-]."""
        a, s = self.held_out_amplitude, self.held_out_amplitude_sigma
        return None if a is None or s is None or not s > 0 else (self.amplitude - a) / s

    @property
    def worst_band(self) -> BandResidual | None:
        """The band of the all-tests residual furthest above its noise."""
        return max(self.all_bands, key=lambda b: b.ratio, default=None)

    @property
    def disagrees(self) -> bool:
        """A held-out difference or a band of the waveform beyond :data:`Z_LIMIT`."""
        zs = [abs(z) for z in (self.frequency_z, self.amplitude_z) if z is not None]
        band = self.worst_band
        return any(z > Z_LIMIT for z in zs) or (band is not None and band.ratio > Z_LIMIT)

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "t_start": self.t_start, "t_end": self.t_end,
                "frequency_hz": self.frequency_hz, "frequency_se_hz": self.frequency_se_hz,
                "amplitude": self.amplitude, "amplitude_se": self.amplitude_se,
                "held_out": {"frequency_hz": self.held_out_frequency_hz, "amplitude": self.held_out_amplitude,
                             "frequency_sigma_hz": self.held_out_frequency_sigma_hz,
                             "amplitude_sigma": self.held_out_amplitude_sigma,
                             "frequency_error": self.frequency_error, "frequency_z": self.frequency_z,
                             "amplitude_error": self.amplitude_error, "amplitude_z": self.amplitude_z,
                             "bands": [b.to_json() for b in self.held_out_bands]},
                "all_tests": {"frequency_hz": self.all_frequency_hz, "amplitude": self.all_amplitude,
                              "bands": [b.to_json() for b in self.all_bands]},
                "even_ratio": finite_or_none(self.even_ratio), "disagrees": self.disagrees, "note": self.note}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> TestCheck:
        ho, al = d["held_out"], d["all_tests"]
        even = d.get("even_ratio")
        return cls(int(d["index"]), float(d["t_start"]), float(d["t_end"]), float(d["frequency_hz"]),
                   float(d["frequency_se_hz"]), float(d["amplitude"]), float(d["amplitude_se"]),
                   json_opt_float(ho["frequency_hz"]), json_opt_float(ho["amplitude"]), json_opt_float(ho["frequency_sigma_hz"]),
                   json_opt_float(ho["amplitude_sigma"]), json_opt_float(al["frequency_hz"]), json_opt_float(al["amplitude"]),
                   tuple(BandResidual.from_json(b) for b in ho["bands"]),
                   tuple(BandResidual.from_json(b) for b in al["bands"]),
                   math.inf if even is None else float(even), str(d.get("note", "")))


# ----------------------------------------------------------------------------------------------
# the measured waveform
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MeasuredWaveform:
    """A test's mean cycle as harmonics, with the cycle-to-cycle scatter.

    Attributes
    ----------
    harmonics : numpy.ndarray
        Complex mean of Y_k over the cycles, k = 1..H, phase from the ``-h -> +h`` switch [output units].
    se : numpy.ndarray
        Standard error of each Y_k (complex scatter over sqrt(n)) [output units].
    frequency_hz, frequency_se_hz : float
        1 / the cycles' mean period P and its standard error [Hz].
    amplitude, amplitude_se : float
        Half the mean waveform's peak-to-peak, and the cycles' scatter of their own over sqrt(n)
        [output units].
    points : tuple of ResponsePoint
        The test's response points (the identification's input).
    """

    harmonics: np.ndarray
    se: np.ndarray
    frequency_hz: float
    frequency_se_hz: float
    amplitude: float
    amplitude_se: float
    points: tuple[ResponsePoint, ...]


def measured_waveform(used: MeasuredTest) -> MeasuredWaveform:
    """The mean cycle and scatter of a test the analysis used (module docstring, stage 2), from its cycle
    fits; its response points are the analysis' own.

    Raises
    ------
    InputError
        Fewer than two cycles long enough to fit.
    """
    fits = used.fits
    if len(fits) < 2:
        assert used.test is not None  # a usable test carries the test as used
        raise InputError(f"test {used.test.index + 1}: fewer than two stable cycles long enough to fit a waveform")
    n_h = min(f.harmonics.size for f in fits)
    Y = np.array([f.harmonics[:n_h] for f in fits])
    n = len(fits)
    mean = Y.mean(axis=0)
    se = np.sqrt(np.mean(np.abs(Y - mean) ** 2, axis=0) / (n - 1))
    # 1 / mean period, as the analysis's table (a mean of 1 / P is biased up by the periods' scatter)
    periods = np.array([f.period for f in fits])
    freq = 1.0 / float(periods.mean())
    amps = np.array([peak_amplitude(y) for y in Y])
    return MeasuredWaveform(mean, se, freq, freq ** 2 * float(periods.std(ddof=1)) / math.sqrt(n),
                            peak_amplitude(mean), float(amps.std(ddof=1) / math.sqrt(n)), used.points)


def _orbit_spread(model: PlantModel, lc: LimitCycle, measured: MeasuredWaveform, rate_hz: float) -> np.ndarray:
    """Each harmonic's spread [output units] over the sampled relay's band of orbits (:func:`_band_std`).

    On an orbit of frequency w the plant answers the relay's harmonic U_k with G(j k w) U_k, and the
    relay's harmonics (in the cycle's phase) do not move with w, so across a band of width dw the
    harmonic moves by |Y_k| |ln G(j k w_hi) - ln G(j k w_lo)|; uniform over the band: that over sqrt(12).
    """
    n = measured.harmonics.size
    width = _band_std(lc, rate_hz)[0] * math.sqrt(12.0)
    if width <= 0:
        return np.zeros(n)
    k = np.arange(1, n + 1)
    w = 2 * math.pi * np.array([lc.frequency_hz - 0.5 * width, lc.frequency_hz + 0.5 * width])
    try:
        G = np.asarray(model.frequency_response(np.outer(k, w).ravel()), complex).reshape(n, 2)
    except (ValueError, ArithmeticError):
        return np.zeros(n)
    with np.errstate(all="ignore"):
        step = np.abs(np.log(G[:, 1] / G[:, 0]))  # the log's imaginary part: the phase step (small: no wrap)
    return np.where(np.isfinite(step), np.abs(measured.harmonics) * step / math.sqrt(12.0), 0.0)


def _bands(measured: MeasuredWaveform, model: np.ndarray, rate_hz: float,
           spread: np.ndarray | None = None) -> tuple[BandResidual, ...]:
    """The residual |measured - model| per band against the noise (module docstring, stage 3).

    A harmonic's noise is its standard error, floored at 3 % of the harmonic and at the sampled
    relay's timing: a switch decided on samples moves by up to Ts = 1 / ``rate_hz`` from the model's
    representative orbit, a pulse of 2 h over Ts whose harmonics are each about Ts / P of the
    fundamental (on a clean simulated FOPDT at 100 Hz the residual of harmonics 2-8 was 3x the
    cycles' scatter, and 0.3 % of the amplitude).
    """
    n = min(measured.harmonics.size, model.size)
    Y = measured.harmonics[:n]
    res = np.abs(Y - model[:n])
    timing = abs(Y[0]) * measured.frequency_hz / rate_hz
    orbits = np.zeros(n) if spread is None else spread[:n]
    sigma = np.sqrt(measured.se[:n] ** 2 + (_HARMONIC_FLOOR * np.abs(Y)) ** 2 + timing ** 2 + orbits ** 2)
    out = []
    for name, lo, hi in BANDS:
        hi = min(hi, n)
        if lo > hi:
            continue
        sl = slice(lo - 1, hi)
        out.append(BandResidual(name, lo, hi, float(np.sqrt(np.mean(res[sl] ** 2))),
                                float(np.sqrt(np.mean(sigma[sl] ** 2))), lo + int(np.argmax(res[sl] / sigma[sl]))))
    return tuple(out)


def _even_ratio(measured: MeasuredWaveform) -> float:
    """RMS of the even harmonics over their noise (the cycles' scatter only) [-]."""
    even = np.arange(2, measured.harmonics.size + 1, 2) - 1
    if even.size == 0:
        return 0.0
    noise = float(np.sqrt(np.mean(measured.se[even] ** 2)))
    rms = float(np.sqrt(np.mean(np.abs(measured.harmonics[even]) ** 2)))
    return rms / noise if noise > 0 else math.inf


# ----------------------------------------------------------------------------------------------
# the check of one test
# ----------------------------------------------------------------------------------------------
def _cycle(model: PlantModel, summary: TestSummary, n_h: int) -> LimitCycle | None:
    """The model's limit cycle under the test's (effective) relay at its rate, or None.

    The relay's MRFT level is read over the model's smooth (``n_h``-harmonic) amplitude, as the
    effective relay's was over the recording's (:func:`mrftcli.analyze.smooth_cycle.predicted_cycle`).
    """
    try:
        return predicted_cycle(summary.predicting_relay, model, summary.rate_hz, n_h)
    except (InputError, IdentificationError, ValueError, ArithmeticError):
        return None


def _band_std(lc: LimitCycle, rate_hz: float) -> tuple[float, float]:
    """The sampled relay's own spread of the predicted frequency [Hz] and amplitude [output units].

    A relay deciding on samples locks onto one of several periodic orbits (a whole number of samples
    per half period, :func:`mrftcli.mrft.lprs.sampled_limit_cycle`); which one depends on the loop's
    history, so the model predicts the band of them, not its centre. The measured mean period is a
    mean of whole-sample periods (patterns may mix neighbouring orbits): its range is the band's,
    widened by one sample. Taken as uniform over that range, its standard deviation is the width over
    sqrt(12) (on a clean FOPDT at 20 Hz, 20-32 samples a cycle, the orbits are 5-10 % apart: the
    centre alone called the loop's own orbit 5 sigma off).
    """
    if lc.rate_hz is None:
        return 0.0, 0.0
    freqs = (*lc.orbits_hz, lc.frequency_hz)
    amps = (*lc.orbits_amplitude, lc.amplitude)
    # one sample of period more: f^2 Ts in frequency
    width_f = max(freqs) - min(freqs) + lc.frequency_hz ** 2 / rate_hz
    return width_f / math.sqrt(12.0), (max(amps) - min(amps)) / math.sqrt(12.0)


def _spread(ident: LtiIdentification, summary: TestSummary) -> tuple[float, float]:
    """The held-out cycle's frequency [Hz] and amplitude [output units] standard deviations from the
    model's parameter std (first order, each parameter's step of one std on the continuous cycle:
    the sampled cycle moves in whole samples, which a small step would not show)."""
    relay = summary.predicting_relay
    try:
        base = relay.limit_cycle(ident.model)
    except (InputError, IdentificationError, ValueError, ArithmeticError):
        return math.inf, math.inf
    var_f = var_a = 0.0
    values = {e.name: e.value for e in ident.estimates}
    for e in ident.estimates:
        if e.known or not e.determined or not (math.isfinite(e.std) and e.std > 0):
            continue
        try:
            lc = relay.limit_cycle(ident.model.with_parameters(**{**values, e.name: e.value + e.std}))
        except (InputError, IdentificationError, ValueError, ArithmeticError):
            continue
        var_f += (lc.frequency_hz - base.frequency_hz) ** 2
        var_a += (lc.amplitude - base.amplitude) ** 2
    return math.sqrt(var_f), math.sqrt(var_a)


def check_test(model: PlantModel, summary: TestSummary, measured: MeasuredWaveform,
               others: Sequence[ResponsePoint], all_model: PlantModel | None) -> TestCheck:
    """One test against the model from ``others`` (held out) and ``all_model`` (module docstring, stage 3).

    Parameters
    ----------
    model : PlantModel
        The structure with its known parameters and ranges.
    summary : TestSummary
        The test as the analysis measured it (its relay and rate).
    measured : MeasuredWaveform
        Its mean cycle.
    others : sequence of ResponsePoint
        The other tests' points.
    all_model : PlantModel or None
        The model identified from all tests.
    """
    n_h = measured.harmonics.size
    base = TestCheck(summary.index, summary.t_start, summary.t_end, measured.frequency_hz, measured.frequency_se_hz,
                     measured.amplitude, measured.amplitude_se, None, None, None, None, None, None,
                     even_ratio=_even_ratio(measured))
    all_lc = None if all_model is None else _cycle(all_model, summary, n_h)
    if all_model is not None and all_lc is not None:
        all_wave = cycle_harmonics(all_lc, n_h)
        base = dataclasses.replace(base, all_frequency_hz=all_lc.frequency_hz, all_amplitude=peak_amplitude(all_wave),
                                   all_bands=_bands(measured, all_wave, summary.rate_hz,
                                                    _orbit_spread(all_model, all_lc, measured, summary.rate_hz)))
    if not others:
        return dataclasses.replace(base, note="no other test to hold it out against")
    try:
        held = identify_points(model, others)
    except IdentificationError as err:
        return dataclasses.replace(base, note=f"the other tests give no model: {err}")
    lc = _cycle(held.model, summary, n_h)
    if lc is None:
        return dataclasses.replace(base, note="the other tests' model has no limit cycle under this relay")
    wave = cycle_harmonics(lc, n_h)
    sf, sa = _spread(held, summary)
    bf, ba = _band_std(lc, summary.rate_hz)
    note = (f"{', '.join(held.undetermined)} not determined by the other tests: their spread is not in "
            "the held-out sigma" if held.undetermined else "")
    return dataclasses.replace(
        base, held_out_frequency_hz=lc.frequency_hz, held_out_amplitude=peak_amplitude(wave),
        held_out_frequency_sigma_hz=math.sqrt(measured.frequency_se_hz ** 2 + sf ** 2 + bf ** 2),
        held_out_amplitude_sigma=math.sqrt(measured.amplitude_se ** 2 + sa ** 2 + ba ** 2),
        held_out_bands=_bands(measured, wave, summary.rate_hz, _orbit_spread(held.model, lc, measured, summary.rate_hz)),
        note=note)


# ----------------------------------------------------------------------------------------------
# the driver
# ----------------------------------------------------------------------------------------------
def _family_name(model: PlantModel) -> str:
    return model.family.upper() if model.family != "declared" else "the declared model"


def test_disagreements(check: TestCheck) -> list[tuple[float, str]]:
    """(size in sigma, text) of each disagreement of one test."""
    out = []
    k = check.index + 1
    fz, az = check.frequency_z, check.amplitude_z
    if fz is not None and abs(fz) > Z_LIMIT and check.frequency_error is not None:
        out.append((abs(fz), f"test {k} differs from the model of the other tests by {100 * check.frequency_error:+.1f} % "
                              f"in frequency ({check.frequency_hz:.4g} Hz measured, {check.held_out_frequency_hz:.4g} Hz "
                              f"predicted, {abs(fz):.1f} sigma)"))
    if az is not None and abs(az) > Z_LIMIT and check.amplitude_error is not None:
        out.append((abs(az), f"test {k} differs from the model of the other tests by {100 * check.amplitude_error:+.1f} % "
                              f"in amplitude ({check.amplitude:.4g} measured, {check.held_out_amplitude:.4g} predicted "
                              f"[output units], {abs(az):.1f} sigma)"))
    for b in check.all_bands:
        if b.ratio > Z_LIMIT:
            share = 100 * b.residual / check.amplitude if check.amplitude > 0 else math.nan
            even = (" (even harmonics: an asymmetric response or an output bias the relay's bias does not "
                    "explain would put it here)" if b.first <= 2 <= b.last and check.even_ratio > Z_LIMIT
                    else "")
            out.append((b.ratio, f"test {k}: waveform residual at {b.describe()} against the model of all tests: "
                                 f"{b.residual:.3g} [output units] RMS, {share:.1f} % of the amplitude, "
                                 f"{b.ratio:.1f}x the noise{even}"))
    return out


def misfit(ident: LtiIdentification | None) -> tuple[float, str] | None:
    """(size in sigma, text) when the model of all tests misses the response points beyond their scatter."""
    if ident is None or ident.chi2_dof is None:
        return None
    dof = 2 * len(ident.points) - sum(not e.known for e in ident.estimates)
    if dof < 1:
        return None
    p = float(chi2_dist.sf(ident.chi2_dof * dof, dof))
    z = float(norm.isf(max(p, 1e-300) / 2))
    if z <= Z_LIMIT:
        return None
    return z, (f"the model of all tests misses the tests' response points: chi2/dof {ident.chi2_dof:.3g} over "
               f"{dof} degrees of freedom (p {'< 1e-16' if p < 1e-16 else f'= {p:.2g}'}; 1 is within their scatter)")


def verdict(model: PlantModel, checks: Sequence[TestCheck], located: Sequence[str],
            effects: Sequence[EffectFit] = ()) -> str:
    """The first line: the effects found (with the held-out error before and after), else consistent, else
    unexplained with where the residual sits."""
    name = _family_name(model)
    if effects:
        return "found: " + "; ".join(
            f"{e.name} ({e.parameter} {e.value:.4g} {e.unit}; held-out error {e.held_out_before:.3f} -> "
            f"{e.held_out_after:.3f}, delta BIC {e.delta_bic:.0f})" for e in effects) + f" on top of {name}"
    if not located:
        held = sum(c.held_out_frequency_hz is not None for c in checks)
        if not held:
            return (f"consistent with {name} within the noise, on one test only (the model is fitted to it, "
                    "nothing is held out: a second relay test checks it)")
        return f"consistent with {name} within the tests' scatter"
    more = f" ({len(located) - 1} more below)" if len(located) > 1 else ""
    return f"unexplained by {name} (no effect of the library improves the held-out tests): {located[0]}{more}"
