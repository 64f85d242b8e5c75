"""Relay tests on process plants, simulated here independently of mrftcli (the oracle of test_families).

The plant is built from its transfer function's polynomials (``scipy.signal.tf2ss``, not the
families' realisations), stepped exactly (zero-order hold) from sample to sample, the delay included
exactly (whole steps plus a fraction, the step split at the fraction). The relay
decides at the controller's rate on the noisy output (e = 0 - y), holds its level, and runs one of:
``mrft`` (tests/relay_rule.py, checks.md section 2), ``ideal``, ``hysteresis`` (switch low when e
falls through -eps, high when it rises through +eps). The bias is the operating point: the plant
sees ``u - bias`` (a bias balanced by the operating point). Between windows the command rests at
the bias. Benchmarks import it too (they put ``tests/`` on ``sys.path``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from relay_rule import relay_step


def polynomials(family: str, p: dict[str, float]) -> tuple[list[float], list[float]]:
    """Numerator and denominator of the delay-free part in s, highest power first."""
    K = p["K"]
    if family == "fopdt":
        return [K], [p["T"], 1.0]
    if family == "sopdt":
        return [K], list(np.polymul([p["T1"], 1.0], [p["T2"], 1.0]))
    if family == "ipdt":
        return [K], [1.0, 0.0]
    if family == "foipdt":
        return [K], [p["T"], 1.0, 0.0]
    if family == "eq2":  # the paper's eq. (2): K Td / (s (Tp s + 1)(Td s + 1))
        return [K * p["Td"]], list(np.polymul(np.polymul([p["Tp"], 1.0], [p["Td"], 1.0]), [1.0, 0.0]))
    raise ValueError(family)


@dataclass(frozen=True)
class Window:
    """One relay window: kind, levels, beta or eps, length in seconds, then a rest at the bias."""

    kind: str
    high: float
    low: float
    beta: float = 0.0
    eps: float = 0.0
    duration: float = 10.0
    rest: float = 3.0


def simulate(family: str, params: dict[str, float], windows: list[Window], rate_hz: float, noise_std: float,
             seed: int = 0, oversample: int = 1, lead: float = 2.0,
             start: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], command, output) sampled at ``rate_hz``; ``noise_std`` [output units] on the output.

    ``start``: the error [output units] a window's relay holds +h until (None: 5 noise std); an
    integrating plant under an MRFT needs a clear excursion, or its lagging output locks the relay up.
    """
    start_e = 5 * noise_std if start is None else start
    rng = np.random.default_rng(seed)
    num, den = polynomials(family, params)
    A, B, C, _ = signal.tf2ss(num, den)
    n = A.shape[0]
    Ts = 1.0 / rate_hz
    dt = Ts / oversample

    def zoh(step: float) -> tuple[np.ndarray, np.ndarray]:
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = A * step, B[:, 0] * step
        E = linalg.expm(M)
        return E[:n, :n], E[:n, n]

    # the delay exactly: d whole fine steps and a fraction; within a step the plant sees the older
    # input for the fraction, then the newer one
    d = int(params["tau"] // dt)
    frac = params["tau"] - d * dt
    Phi_a, Gam_a = zoh(frac)
    Phi_b, Gam_b = zoh(dt - frac)
    buf = [0.0] * (d + 2)  # plant input (deviation from the bias) of the last d + 2 fine steps
    x = np.zeros(n)
    ts, us, ys = [], [], []
    t = 0.0
    schedule = []
    for w in windows:
        schedule.append((None, lead if not schedule else w.rest))
        schedule.append((w, w.duration))
    bias0 = windows[0].high / 2 + windows[0].low / 2
    for w, dur in schedule:
        steps = int(round(dur * rate_hz))
        bias = bias0 if w is None else 0.5 * (w.high + w.low)
        h = 0.0 if w is None else 0.5 * (w.high - w.low)
        s, ext, started = 1.0, 0.0, False
        for _ in range(steps):
            y = float(C[0] @ x) + noise_std * rng.standard_normal()
            e = -y
            if w is not None:
                if not started:
                    # hold +h until the error is clearly negative (5 noise std), so that the first
                    # switch is not decided on the noise (a plain MRFT can lock up there)
                    s = 1.0
                    if e < -start_e - 1e-12:
                        s, ext, started = -1.0, e, True
                elif w.kind == "mrft":
                    s, ext = relay_step(s, ext, e, w.beta)
                elif w.kind == "ideal":
                    s = 1.0 if e > 0 else (-1.0 if e < 0 else s)
                elif s > 0 and e <= -w.eps:
                    s = -1.0
                elif s < 0 and e >= w.eps:
                    s = 1.0
            u = bias + h * s if w is not None else bias
            ts.append(t)
            us.append(u)
            ys.append(y)
            for _ in range(oversample):
                buf.append(u - bias)
                buf.pop(0)
                x = Phi_b @ (Phi_a @ x + Gam_a * buf[0]) + Gam_b * buf[1]
            t += Ts
            bias0 = bias
    return np.array(ts), np.array(us), np.array(ys)


def write_csv(path: str, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    """A CSV with the KSTAR files' columns (time, u_relay, y_output)."""
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="time,u_relay,y_output", comments="",
               fmt="%.10g")
