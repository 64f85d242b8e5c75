"""Issue 41: each MRFT test's frequency held out (predicted from the other tests) by several routes, on every
test the campaign flew (a test a route gives no prediction for, or a log it refuses, is a miss).

Routes through the CLI, as a user runs them (``mrft-ident analyze LOG ... --json``; the held-out prediction is
``tests[i].held_out`` of the record):

* ``eq2``: ``--tp TP`` (eq. (2), the default): since b57d0d0 eq. (2) fitted to the other tests' fundamental and
  3rd-harmonic response points where they are one eq. (2) plant, else the paper's UFM point solve of their
  frequencies (analyze/held_out_harmonic.py, analyze/held_out.py; ``points_h13`` below is the same fit ungated,
  on a declared eq. (2));
* ``--model-file`` with a declared structure (fitted to the other tests' fundamental and harmonic response
  points, gain and phase, each weighted by its scatter): eq. (2) itself (``eq2_declared``), eq. (2) with a lead
  zero in the measurement path (``lead``), with a zero and a pole (``lead_lag``: an estimator's frequency-
  dependent lead or lag, such as EKF3's altitude against SITL's, docs/benchmarks/sitl.md), and eq. (2) with Tp
  free (``tp_free``).

Routes in this process (eq. (2) fitted by least squares to the other tests' mean frequencies, each weighted by
its AR(1) standard error, ``mrft.sem.mean_sem``; tau >= 0): at the nominal beta or at the measured effective one,
with the relay continuous or sampled at the test's rate (``mrft_limit_cycle(..., rate_hz)``), with the other
tests' mean amplitudes as well (``nominal_sampled_amp``: the question whether amplitudes pin what the
frequencies leave free), and with a lead allowed (``effective_continuous_lead``: tau down to -Tp/2 through
``mrft.lprs.lead_cycle``, as ``mrft-ident delay`` takes EKF3's lead).

Routes on the response points in this process (``points_h1``, ``points_h13``, ``points_h135``, ``points_raw``):
eq. (2) declared (``eq2_declared``'s structure) fitted to the other tests' response points as ``analyze
--model-file`` fits them (``analyze.general.identify_points``, the test predicted under its effective relay),
with the harmonics named: the fundamentals alone, with the 3rd, with the 3rd and 5th (harmonics' standard
errors floored at 3 %, as analyze does), and the 3rd and 5th each weighted by its measured scatter alone
(no floor): the question whether eq. (2)'s own held-out should fit harmonics, and which
(benchmarks/bench_held_out_harmonics.py).
"""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.lprs import lead_cycle, mrft_limit_cycle
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.sem import mean_sem
from mrftcli.segment import segment

__all__ = ["MODEL_FILES", "POINT_ROUTES", "RouteResult", "cli_route", "fit_route", "harmonic_residuals", "held_out_routes",
           "points_route"]

_EQ2 = "K*exp(-tau*s)/(s*(Td*s + 1)*(Tp*s + 1))"
_K = 'K   = { range = [0.1, 10000] }\n'
_TD = 'Td  = { range = [0.05, 50], unit = "s" }\n'
_TAU = 'tau = { range = [0, 0.2], unit = "s" }\n'
_TP = 'Tp  = { value = @TP@, unit = "s" }\n'
#: the declared structures (``@TP@``: the sidecar's Tp [s]); ranges wide and physical
MODEL_FILES = {
    "eq2_declared": f'transfer_function = "{_EQ2}"\n[parameters]\n{_K}{_TD}{_TAU}{_TP}',
    "lead": ('transfer_function = "K*(a*s + 1)*exp(-tau*s)/(s*(Td*s + 1)*(Tp*s + 1))"\n[parameters]\n'
             f'{_K}{_TD}{_TAU}{_TP}a   = {{ range = [0.0001, 0.1], unit = "s" }}\n'),
    "lead_lag": ('transfer_function = "K*(a*s + 1)*exp(-tau*s)/((b*s + 1)*s*(Td*s + 1)*(Tp*s + 1))"\n'
                 f'[parameters]\n{_K}{_TD}{_TAU}{_TP}a   = {{ range = [0.0001, 0.2], unit = "s" }}\n'
                 'b   = { range = [0.0001, 0.2], unit = "s" }\n'),
    "tp_free": (f'transfer_function = "{_EQ2}"\n[parameters]\n{_K}{_TD}{_TAU}'
                'Tp  = { range = [0.001, 0.2], unit = "s" }\n'),
}


@dataclass(frozen=True)
class RouteResult:
    """One route over one log: the tests flown and each held-out error (None: no prediction, a miss)."""

    flown: int
    errors: tuple[float | None, ...]

    @property
    def within(self) -> int:
        return sum(e is not None and abs(e) <= 0.05 for e in self.errors)


def _side(log: Path) -> dict:
    return json.loads(Path(f"{log}.json").read_text())


def cli_route(log: Path, route: str, workdir: Path) -> RouteResult:
    """``mrft-ident analyze LOG --json`` by route ``eq2`` (``--tp``) or a declared structure of
    :data:`MODEL_FILES` (``--model-file``): each test's held-out error from the record."""
    side = _side(log)
    cmd = [sys.executable, "-m", "mrftcli", "analyze", str(log), "--loop", side["loop"]]
    if route == "eq2":
        cmd += ["--tp", repr(side["tp_s"])]
    else:
        spec = workdir / f"{log.stem}_{route}.toml"
        spec.write_text(MODEL_FILES[route].replace("@TP@", repr(side["tp_s"])))
        cmd += ["--model-file", str(spec)]
    out = workdir / f"{log.stem}_{route}.json"
    proc = subprocess.run([*cmd, "--json", str(out)], capture_output=True, text=True)
    flown = len(side["tests"])
    if proc.returncode not in (0, 6) or not out.exists():  # refused: every test a miss
        return RouteResult(flown, (None,) * flown)
    errors = []
    for t in json.loads(out.read_text())["tests"]:
        predicted = (t.get("held_out") or {}).get("frequency_hz")
        errors.append(None if predicted is None else predicted / float(t["frequency_hz"]) - 1.0)
    return RouteResult(flown, tuple(errors + [None] * (flown - len(errors))))


def _cycle(tp: float, p: np.ndarray, test, beta: str, sampled: bool) -> tuple[float, float]:
    Td, tau, K = math.exp(p[0]), float(p[1]), math.exp(p[2])
    b = test.beta_nominal if beta == "nominal" else test.beta_effective
    if tau < 0:  # a lead (the ``_lead`` routes): eq. (2)'s cycle as ``mrft-ident delay`` takes it, continuous relay
        omega, a_unit = lead_cycle(tp, Td, tau, b)
        return omega / (2 * math.pi), test.h * K * Td * a_unit / omega
    lc = mrft_limit_cycle(LoopModel(tp, Td, tau, K), b, test.h, test.rate_hz if sampled else None)
    return lc.frequency_hz, lc.amplitude


def _fit(tp: float, others: list, cycle: Callable, amplitudes: bool, td0: float,
         tau_min: float = 0.0) -> np.ndarray | None:
    """Td, tau, K (as ln Td, tau, ln K) by weighted least squares on the other tests' log frequencies (and log
    amplitudes), each over its AR(1) standard error; the best of six starts."""
    def residuals(p: np.ndarray) -> list[float]:
        r = []
        for t in others:
            f, a = cycle(p, t)
            r.append(math.log(f / t.frequency_hz_mean) * t.frequency_hz_mean / mean_sem(t.frequency_hz))
            if amplitudes:
                r.append(math.log(a / t.amplitude_mean) * t.amplitude_mean / mean_sem(t.amplitude))
        return r

    best = None
    for td in (0.3 * td0, td0, 3.0 * td0):
        for tau in (0.0, 0.01):
            k0 = others[0].amplitude_mean / cycle(np.array([math.log(td), tau, 0.0]), others[0])[1]
            try:
                s = least_squares(residuals, [math.log(td), tau, math.log(k0)], x_scale=[0.3, 0.003, 0.3],
                                  bounds=([math.log(0.02), tau_min, -30.0], [math.log(100.0), 0.3, 30.0]))
            except (ValueError, ArithmeticError):
                continue
            if best is None or s.cost < best.cost:
                best = s
    return None if best is None else best.x


def fit_route(log: Path, route: str) -> RouteResult:
    """An in-process route (module docstring): ``{nominal|effective}_{continuous|sampled}[_amp|_lead]``
    (``_lead``: tau down to -Tp/2, a lead, as ``mrft-ident delay`` allows; continuous relay)."""
    side = _side(log)
    parts = route.split("_")
    beta, sampled, amplitudes = parts[0], parts[1] == "sampled", parts[-1] == "amp"
    tau_min = -0.5 * side["tp_s"] if parts[-1] == "lead" else 0.0
    tests = segment(read_flight(log, ReadOptions(loop=side["loop"])))
    def cycle(p: np.ndarray, t) -> tuple[float, float]:
        return _cycle(side["tp_s"], p, t, beta, sampled)

    td0 = 4.0 if side["loop"] == "altitude" else 0.5
    errors: list[float | None] = []
    for i, test in enumerate(tests):
        others = [t for j, t in enumerate(tests) if j != i]
        p = _fit(side["tp_s"], others, cycle, amplitudes, td0, tau_min) if len(others) >= 2 else None
        errors.append(None if p is None else cycle(p, test)[0] / test.frequency_hz_mean - 1.0)
    flown = len(side["tests"])
    return RouteResult(flown, tuple(errors + [None] * (flown - len(errors))))


#: the response-point routes: (harmonics fitted besides the fundamental, harmonics' standard errors floored at 3 %)
POINT_ROUTES = {"points_h1": ((), True), "points_h13": ((3,), True), "points_h135": ((3, 5), True),
                "points_raw": ((3, 5), False)}


@functools.lru_cache(maxsize=4)
def _measured(log: Path) -> tuple:
    """Every test of ``log`` screened and measured as ``analyze --model-file`` does (once per log)."""
    from mrftcli.analyze import general
    from mrftcli.analyze.options import RelayOptions

    side = _side(log)
    return tuple(general.measure_tests(read_flight(log, ReadOptions(loop=side["loop"]), echo_warnings=False),
                                       RelayOptions(), (), 3))


def points_route(log: Path, route: str) -> RouteResult:
    """A response-point route (module docstring, :data:`POINT_ROUTES`): eq. (2) declared, fitted to the other
    tests' fundamentals and the named harmonics, each test predicted under its effective relay."""
    from mrftcli.analyze import general
    from mrftcli.mrft.identify import identify
    from mrftcli.mrft.model_file import parse_model_spec

    side = _side(log)
    harmonics, floored = POINT_ROUTES[route]
    model = parse_model_spec(tomllib.loads(MODEL_FILES["eq2_declared"].replace("@TP@", repr(side["tp_s"]))))
    measured = _measured(log)
    points = [p for m in measured for p in m.points if p.harmonic == 1 or p.harmonic in harmonics]
    n_h = {m.summary.index: min(f.harmonics.size for f in m.fits) for m in measured if m.summary and m.fits}
    errors: list[float | None] = []
    for t in (m.summary for m in measured if m.summary is not None):
        kept = general.identify_points
        if not floored:  # the harmonics over their measured scatter alone: analyze's fit without its floor
            general.identify_points = lambda model, pts: identify(pts, model)
        try:
            ho = general.held_out(model, t, [p for p in points if p.test != t.index], n_h.get(t.index))
        finally:
            general.identify_points = kept
        errors.append(None if ho.frequency_hz is None else ho.frequency_hz / t.frequency_hz - 1.0)
    flown = len(side["tests"])
    return RouteResult(flown, tuple(errors + [None] * (flown - len(errors))))


def harmonic_residuals(log: Path) -> list[str]:
    """Each test's fundamental, 3rd and 5th harmonic against eq. (2) declared fitted to every test's fundamentals:
    the gain [%] and phase [deg] the harmonics add beyond it, beside their measured standard errors (why fitting
    a harmonic helps or hurts a held-out prediction: a harmonic off by more than its scatter is a bias)."""
    from mrftcli.analyze import general
    from mrftcli.mrft.model_file import parse_model_spec

    side = _side(log)
    model = parse_model_spec(tomllib.loads(MODEL_FILES["eq2_declared"].replace("@TP@", repr(side["tp_s"]))))
    points = [p for m in _measured(log) for p in m.points]
    fit = general.identify_points(model, [p for p in points if p.harmonic == 1])
    response = fit.model.frequency_response(np.array([p.omega for p in points]))
    lines = []
    for p, g in zip(points, response):
        phase = math.degrees((p.phase - np.angle(g) + math.pi) % (2 * math.pi) - math.pi)
        lines.append(f"test {p.test + 1} k {p.harmonic} at {p.omega / (2 * math.pi):6.2f} Hz: gain "
                     f"{math.log(p.gain / abs(g)) * 100:+6.1f} % (se {p.se_log_gain * 100:4.1f}), phase {phase:+6.1f} deg "
                     f"(se {math.degrees(p.se_phase):4.1f})")
    return lines


CLI_ROUTES = ("eq2", *MODEL_FILES)
FIT_ROUTES = ("effective_continuous", "nominal_continuous", "nominal_sampled", "nominal_sampled_amp",
              "effective_continuous_lead")


def held_out_routes(logs: list[Path], routes: tuple[str, ...] = CLI_ROUTES + FIT_ROUTES + tuple(POINT_ROUTES)
                    ) -> dict[str, dict[str, RouteResult]]:
    """Every route over every log, printed as it goes: {route: {log name: result}}."""
    out: dict[str, dict[str, RouteResult]] = {}
    with tempfile.TemporaryDirectory(prefix="mrft_held_out_") as tmp:
        for route in routes:
            out[route] = {}
            for log in logs:
                res = (cli_route(log, route, Path(tmp)) if route in CLI_ROUTES
                       else points_route(log, route) if route in POINT_ROUTES else fit_route(log, route))
                out[route][log.stem] = res
                cells = ", ".join("refused" if e is None else f"{e * 100:+.1f}" for e in res.errors)
                print(f"    {route:22s} {log.stem:18s} {cells}", flush=True)
            n = sum(r.flown for r in out[route].values())
            hits = sum(r.within for r in out[route].values())
            errs = [abs(e) for r in out[route].values() for e in r.errors if e is not None]
            print(f"  {route}: held out within 5 % {hits}/{n} (no prediction counts as a miss); median |error| "
                  f"{np.median(errs) * 100:.1f} %, max {max(errs) * 100:.1f} %", flush=True)
    return out
