"""An independent, exact closed-loop MRFT flight simulation used by the segmenter tests.

Written separately from :mod:`mrftcli.sim.flight` so that the segmenter and the analysis are checked
against a second implementation. The plant G(s) = K Td e^{-tau s} / (s (Tp s+1)(Td s+1)) is
integrated exactly between controller ticks (matrix exponentials; the delayed zero-order-hold input
changes once inside each tick, at t_n + (tau mod dt)), the MRFT switches on noisy samples with the
HEAR rule of ``../shared/reference/checks.md`` section 2, and a PD controller holds the setpoint
around the tests (take-off ramp, hover, holds, landing ramp).

This module holds no tests; ``test_segment*.py`` and ``test_analyze*.py`` import it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from mrftcli.io.logtypes import FlightLog, Signal


def _zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * dt
    M[:n, n] = B * dt
    E = expm(M)
    return E[:n, :n], E[:n, n]


@dataclass
class SimLog:
    t: np.ndarray
    command: np.ndarray
    y_meas: np.ndarray
    y_true: np.ndarray
    setpoint: np.ndarray
    test_windows: list  # (t_start, t_end, beta, h)


def simulate_relay_flight(
    Tp: float,
    Td: float,
    tau: float,
    K: float,
    tests: list[tuple[float, float, float]],  # (beta, h, duration)
    *,
    rate_hz: float = 200.0,
    noise_std: float = 0.0005,
    bias: float = 0.5,
    setpoint: float = 1.0,
    takeoff_s: float = 2.0,
    hold_s: float = 3.0,
    seed: int = 0,
) -> SimLog:
    """Simulate take-off, hold, MRFT tests separated by holds, landing. Exact at the samples."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / Td, K], [0.0, 0.0, -1.0 / Tp]])
    B = np.array([0.0, 0.0, 1.0 / Tp])
    m = int(np.floor(tau / dt + 1e-12))
    r = tau - m * dt
    Phi1, Gam1 = _zoh(A, B, r) if r > 0 else (np.eye(3), np.zeros(3))
    Phi2, Gam2 = _zoh(A, B, dt - r)

    # Schedule: phases as (kind, duration, beta, h)
    phases = [("takeoff", takeoff_s, 0, 0), ("hold", hold_s, 0, 0)]
    for beta, h, dur in tests:
        phases.append(("mrft", dur, beta, h))
        phases.append(("hold", hold_s, 0, 0))
    phases.append(("land", takeoff_s, 0, 0))
    total = sum(p[1] for p in phases)
    n = int(round(total * rate_hz))
    t = np.arange(n) * dt
    cmd = np.empty(n)
    ym = np.empty(n)
    yt = np.empty(n)
    sp = np.empty(n)
    u_dev = np.zeros(n + m + 2)  # deviation command history (plant input, before delay)
    x = np.zeros(3)
    # start on the ground at y = 0 (output offset: y_abs = x1)
    windows = []
    k = 0
    # PD gains for the hold: loosely tuned from the model (slow and safe)
    wc = 0.25 / (tau + Tp + 0.02)
    kp = wc**2 / (K) * 1.0
    kd = 1.5 * wc / K
    prev_e = 0.0
    de_f = 0.0
    for kind, dur, beta, h in phases:
        n_ph = int(round(dur * rate_hz))
        state = 0
        first = True
        e_ext = 0.0
        t0 = t[k] if k < n else total
        for _ in range(n_ph):
            if k >= n:
                break
            if kind == "takeoff":
                ref = setpoint * min(1.0, (t[k] - t0) / max(dur, dt))
            elif kind == "land":
                ref = setpoint * max(0.0, 1.0 - (t[k] - t0) / max(dur, dt))
            else:
                ref = setpoint
            y_true = x[0]
            y = y_true + noise_std * rng.standard_normal()
            e = ref - y
            if kind == "mrft" and state == 0:
                # start as a plain relay with a small hysteresis so the first switch happens with the
                # output already moving; from then on the MRFT rule (checks.md section 2)
                state = 1 if e >= 0 else -1
                first = True
            if kind == "mrft":
                hyst = 3.0 * noise_std + 1e-9
                if first:
                    if state * e <= -hyst:
                        state = -state
                        e_ext = e
                        first = False
                elif state > 0:
                    # track e_max since the switch; the extra "turned by hyst" condition only matters
                    # at start-up, when an early noisy switch leaves the output on the wrong side
                    e_ext = max(e_ext, e)
                    if e <= -beta * e_ext and e_ext - e > hyst:
                        state = -1
                        e_ext = e
                else:
                    e_ext = min(e_ext, e)
                    if e >= -beta * e_ext and e - e_ext > hyst:
                        state = +1
                        e_ext = e
                u = state * h
            else:
                # filtered derivative (time constant 50 ms) so sensor noise does not dominate
                de_f += (dt / (0.05 + dt)) * ((e - prev_e) / dt - de_f)
                u = float(np.clip(kp * e + kd * de_f, -1.0, 1.0))
            prev_e = e
            cmd[k] = bias + u
            ym[k] = y
            yt[k] = y_true
            sp[k] = ref
            u_dev[k + m + 1] = u  # plant sees it m ticks + r later
            # propagate over [t_k, t_k + r) with the older input, then [t_k + r, t_k+1) with the newer
            x = Phi1 @ x + Gam1 * u_dev[k]
            x = Phi2 @ x + Gam2 * u_dev[k + 1]
            k += 1
        if kind == "mrft":
            windows.append((t0, t0 + dur, beta, h))
    return SimLog(t, cmd, ym, yt, sp, windows)


def to_flight(sim: SimLog, *, with_beta: bool = True, with_setpoint: bool = True,
              t_cmd: np.ndarray | None = None, keep: np.ndarray | None = None) -> FlightLog:
    """Wrap a SimLog as a FlightLog (optionally with altered command timestamps / dropped samples)."""
    t = sim.t if t_cmd is None else t_cmd
    idx = np.arange(t.size) if keep is None else np.flatnonzero(keep)
    command = Signal(t[idx], sim.command[idx])
    output = Signal(t[idx], sim.y_meas[idx])
    beta = None
    if with_beta:
        beta = Signal([w[0] for w in sim.test_windows], [w[2] for w in sim.test_windows])
    setpoint = Signal(sim.t, sim.setpoint) if with_setpoint else None
    return FlightLog(path="<sim>", loop="altitude", command=command, output=output, beta=beta,
                     setpoint=setpoint)


def flight_from_simulated(sf, *, with_beta: bool = True) -> FlightLog:
    """A FlightLog from :func:`mrftcli.sim.flight.simulate_flight` output, without writing a file."""
    topics = {tp.name: tp for tp in sf.topics}
    beta = None
    if with_beta and "/mrft/beta" in topics:
        b = topics["/mrft/beta"]
        beta = Signal(b.t, b.fields["data"])
    return FlightLog(path="<simulated>", loop=sf.spec.loop, command=Signal(sf.t, sf.command),
                     output=Signal(sf.t, sf.output_measured), beta=beta,
                     setpoint=Signal(sf.t, sf.setpoint))


def simulate_paper_flight(Tp, Td, tau, K, betas, *, loop="altitude", amplitude=None, cycles=12.0, seed=0,
                          noise_std=None, switching="hear", hover_s=2.0, hold_s=2.0):
    """The project's simulator with tests planned for a given amplitude (output units)."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight

    model = LoopModel(Tp, Td, tau, K)
    if amplitude is None:
        amplitude = 0.05 if loop == "altitude" else np.deg2rad(10.0)
    tests = tuple(plan_test(model, b, amplitude, cycles=cycles, min_duration=4.0) for b in betas)
    spec = FlightSpec(model=model, tests=tests, loop=loop, switching=switching, seed=seed, noise_std=noise_std,
                      hover_s=hover_s, hold_s=hold_s)
    return simulate_flight(spec)
