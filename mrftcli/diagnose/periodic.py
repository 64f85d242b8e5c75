"""Exact periodic MRFT solutions of the augmented loop, from its Fourier series (no time stepping).

Diagnosis needs hundreds of limit cycles per log, each a smooth function of the parameters. The
continuous relay of :func:`mrftcli.diagnose.limit_cycles.periodic_cycle` finds them by simulating
tens of cycles tick by tick (about 13 ms each); here the periodic solution is written down instead,
the way the LPRS does for the symmetric relay (:mod:`mrftcli.mrft.lprs`), and generalised to the
asymmetric relay levels, actuator ramps and the two nonlinearities of the candidate library
(about 0.3 ms each).

Plant (deviation coordinates, the relay's -h -> +h switch at t = 0, its +h -> -h switch at t = H)::

    w(t) = relay level + input_bias, optionally slewed at +-R     (plant input [command units])
    p'   = (w(t - tau) - p) / Tp                                  (propulsion)
    v'   = -v / Td + K p     (or -c v|v| + K p: quadratic drag)
    y'   = v,  measured through 1 / (T_lag s + 1)

For a linear plant each harmonic k of the periodic output is Y_k = 2 G(j k Omega) c_k, c_k the
Fourier coefficient of w (jumps, or kinks of the ramps, in closed form). The integrator makes the
mean of w vanish, which fixes the high-time fraction H / P; the output's constant is free and the
two MRFT switching conditions (checks.md section 2: y(H) = -beta_dn min_[0,H] y and
y(0) = -beta_up max_[H,P] y) fix it and the period P (a scalar root in P).

Quadratic drag is solved by a fixed point on the drag's remainder after its describing-function
linearisation (the remainder is a small fraction of the inertia at test frequencies, so it
converges in a few steps). Thrust rectification (the propulsion lag acts on the rotor speed, thrust
goes with its square) squares the rotor speed's periodic response on a grid. The two can act at
once: the rectified thrust is the force in the drag's fixed point, and the high-time fraction is
found in the same iteration (the mean force balances the mean drag).

Units: times in seconds, the output in its own units, the command in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

__all__ = ["CyclePlant", "PeriodicSolution", "periodic_solution", "cycle_at_period", "N_SERIES"]

#: harmonics kept in the series (the output's harmonics fall like 1/k^4: 160 leave ~1e-9 of it)
N_SERIES = 160
_M = 1024  # grid points per period for the extrema (refined by a parabola)
_K = np.arange(1, N_SERIES + 1)
#: the secant ends when its step times the step before it is below this fraction of rtol P^2
_SECANT_MARGIN = 1e-2
_JK = 1j * _K
#: Gauss-Legendre nodes on [-1, 1] for the square root of an actuator ramp (thrust rectification)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)


@dataclass(frozen=True)
class CyclePlant:
    """The augmented loop model as the periodic solver sees it.

    Attributes
    ----------
    Tp, Td, tau, K : float
        Linear model of eq. (2) [s, s, s, output units/(command unit s^2)]; Td = inf: no drag.
    level_high, level_low : float
        Plant input w during the relay's high and low halves [command units], relative to the
        trim (a symmetric relay without bias: +h, -h).
    rate_limit : float
        Actuator slew rate [command units/s]; 0 = steps.
    sensor_lag : float
        Extra first-order measurement lag [s]; 0 = none.
    quadratic_drag : float
        c of v' = -c v|v| + K p [1/output unit], replacing 1/Td when > 0.
    hover_thrust : float
        Thrust rectification: hover thrust above the zero-thrust command [command units]; 0 = none
        (the lag Tp acts on rotor speed, thrust ~ speed^2).
    """

    Tp: float
    Td: float
    tau: float
    K: float = 1.0
    level_high: float = 1.0
    level_low: float = -1.0
    rate_limit: float = 0.0
    sensor_lag: float = 0.0
    quadratic_drag: float = 0.0
    hover_thrust: float = 0.0


@dataclass(frozen=True)
class PeriodicSolution:
    """One periodic MRFT cycle.

    ``period`` P [s], ``high`` H [s] (time at the high level); ``Y`` the one-sided harmonics of the
    measured output (index 0 its mean, y ~ Y_0 + Re sum_k Y_k e^{j k 2 pi t / P}, t from the
    -h -> +h switch), ``N_SERIES + 1`` of them; ``U`` the same for the plant input before the delay.
    """

    period: float
    high: float
    Y: np.ndarray
    U: np.ndarray
    slope: float = 0.0  # d(switching residual)/dP at the root (a warm start for a nearby plant)
    state: tuple | None = None  # the nonlinear fixed point (fraction, remainder, damping): a warm start

    def waveform(self, t: np.ndarray, n_harm: int | None = None) -> np.ndarray:
        """The output at times ``t`` [s] after the -h -> +h switch (the first ``n_harm`` harmonics)."""
        n = self.Y.size - 1 if n_harm is None else n_harm
        k = np.arange(1, n + 1)
        w = 2.0 * np.pi / self.period
        return self.Y[0].real + np.real(np.exp(1j * np.outer(np.asarray(t, float), k * w)) @ self.Y[1:n + 1])


class _InputSeries:
    """Fourier coefficients c_k (k >= 1, two-sided convention) of the plant input before the delay, at
    one period P [s] and levels ``a``, ``b``; :meth:`at` gives them for a high time H [s]. What does not
    depend on H is computed once (a fixed point on the high-time fraction asks for many H at one P;
    the arithmetic, and so every bit, is the one of a single evaluation)."""

    def __init__(self, pl: CyclePlant, P: float, k: np.ndarray, a: float, b: float) -> None:
        self.P, self.rate = P, pl.rate_limit
        self.phase: tuple[float, np.ndarray] | None = None  # the last H asked for and exp(-j k w H)
        w = 2.0 * np.pi / P
        jkw = 1j * k * w
        self.neg_jkw = -jkw
        jump = a - b
        self.jump = jump
        if self.rate > 0:
            self.d = jump / self.rate
            e = np.exp(-jkw * self.d)
            # kinks of the trapezoid: w'' = R (delta(t) - delta(t - d) - delta(t - H) + delta(t - H - d))
            self.head = self.rate * (1.0 - e)
            self.den = P * jkw * jkw
        else:
            self.den = P * jkw

    def at(self, H: float) -> np.ndarray | None:
        """c_k at high time H [s]; None when a ramp never reaches the level (a triangle wave: not a
        regular cycle)."""
        if self.rate > 0 and not self.d < min(H, self.P - H):
            return None
        e = np.exp(self.neg_jkw * H)
        self.phase = (H, e)  # the output at the switch to the low level reads it again (:meth:`_Series.at_high`)
        return (self.head if self.rate > 0 else self.jump) * (1.0 - e) / self.den


class _Force:
    """The propulsion's periodic output (force [command units]) at one period P [s] as a function of
    the high-time fraction (:meth:`at`); what does not depend on the fraction is computed once (the
    fixed point of :meth:`_Series._nonlinear` asks for many fractions at one period; the arithmetic,
    and so every bit, is the one of a single evaluation).

    Linear propulsion: p = w / (Tp s + 1). Thrust rectification: the rotor speed (relative to hover)
    lags the speed the command asks for, sqrt(1 + w / F), and the thrust is F (speed^2 - 1).
    """

    def __init__(self, pl: CyclePlant, P: float, s: np.ndarray, a: float, b: float) -> None:
        self.pl, self.P, self.a, self.b = pl, P, a, b
        self.lag = pl.Tp * s + 1.0
        F = pl.hover_thrust
        self.ok = not F > 0 or 1.0 + b / F > 0
        if not self.ok:
            return
        if F > 0:
            self.ra, self.rb = ra, rb = math.sqrt(1.0 + a / F), math.sqrt(1.0 + b / F)
            self.series = _InputSeries(replace_levels(pl, ra, rb), P, _K, ra, rb)
            self.kw = None
            if pl.rate_limit > 0:
                # the speed target under a slewed command is the square root of the ramp: the ramp
                # between the speed levels plus a bump over each ramp, added by Gauss-Legendre quadrature
                d = (a - b) / pl.rate_limit
                x = 0.5 * d * (_GL_X + 1.0)
                wq = 0.5 * d * _GL_W / P
                frac_r = x / d
                up = np.sqrt(1.0 + (b + (a - b) * frac_r) / F) - (rb + (ra - rb) * frac_r)
                dn = np.sqrt(1.0 + (a - (a - b) * frac_r) / F) - (ra - (ra - rb) * frac_r)
                w = 2.0 * np.pi / P
                ph = np.exp(-1j * np.outer(_K * w, x))
                self.kw, self.bump_up, self.bump_dn = _K * w, ph @ (wq * up), ph @ (wq * dn)
                self.bump_mean = float(wq @ (up + dn))
        else:
            self.series = _InputSeries(pl, P, _K, a, b)

    def at(self, frac: float):
        """Its harmonics (k >= 1, two-sided, before the delay), its mean, the mean's derivative in
        ``frac`` and the plant input's harmonics, or None."""
        if not self.ok:
            return None
        pl, P, a, b = self.pl, self.P, self.a, self.b
        F = pl.hover_thrust
        if F > 0:
            ra, rb = self.ra, self.rb
            H = frac * P
            c = self.series.at(H)
            if c is None:
                return None
            mean_sp = frac * ra + (1.0 - frac) * rb
            if self.kw is not None:
                c = c + self.bump_up + np.exp(-1j * self.kw * H) * self.bump_dn
                mean_sp += self.bump_mean
            Wk = c / self.lag
            om = mean_sp + np.fft.irfft(np.concatenate([[0.0], Wk, np.zeros(_M // 2 - N_SERIES)]) * _M, _M)
            T = np.fft.rfft(F * (om * om - 1.0)) / _M
            return T[1:N_SERIES + 1], T[0].real, 2.0 * F * mean_sp * (ra - rb), 2.0 * c
        c = self.series.at(frac * P)
        if c is None:
            return None
        return c / self.lag, frac * a + (1.0 - frac) * b, a - b, 2.0 * c


class _Series:
    """The periodic output of one plant at a given period (its constant still free)."""

    def __init__(self, pl: CyclePlant, P: float, warm: list | None = None) -> None:
        self.ok = True
        self.phase: tuple[float, np.ndarray] | None = None  # (H, exp(-j k w H)) when the input series had it
        k = _K
        w = 2.0 * np.pi / P
        s = _JK * w
        a, b = pl.level_high, pl.level_low
        lag = np.exp(-s * pl.tau)
        meas = 1.0 / (pl.sensor_lag * s + 1.0) if pl.sensor_lag > 0 else 1.0
        if pl.hover_thrust > 0 or pl.quadratic_drag > 0:
            Yk, frac, U = self._nonlinear(pl, P, s, lag, a, b, warm)
        else:
            if not (a > 0 > b):
                self.ok = False
                return
            frac = -b / (a - b)  # the integrator: the input's mean vanishes
            inp = _InputSeries(pl, P, k, a, b)
            c = inp.at(frac * P)
            if c is None:
                self.ok = False
                return
            self.phase = inp.phase
            drag = 1.0 / pl.Td if np.isfinite(pl.Td) else 0.0
            G = pl.K / (s * (pl.Tp * s + 1.0) * (s + drag))
            Yk = 2.0 * G * c * lag
            U = 2.0 * c
        if Yk is None:
            self.ok = False
            return
        self.Yk = Yk * meas
        self.U = U
        self.P = P
        self.H = frac * P
        self.w = w
        self.k = k

    @staticmethod
    def _nonlinear(pl, P, s, lag, a, b, warm=None):
        """Thrust rectification and/or quadratic drag: a fixed point on the high-time fraction (the
        mean force must balance the mean drag, zero without quadratic drag) and, with quadratic drag
        v' = -c v|v| + K p, on the drag's remainder after its describing-function linearisation.

        ``warm``: a one-item list holding the converged (fraction, remainder, damping) of a nearby
        plant or period (it is updated here), the start of the fixed point; None or empty: the cold
        start. The converged cycle does not depend on the start (nor on the damping, which only sets
        the contraction): a warm start that fails to converge falls back to the cold one."""
        if not pl.quadratic_drag > 0:
            # (thrust rectification alone keeps its cold start: its pair fits' leave-one-test-out
            # refits have flat directions whose end point, and the verdict, move with the last bits)
            return _Series._fixed_point(pl, P, s, lag, a, b, None, stall=False)[:3]
        if warm:
            got = _Series._fixed_point(pl, P, s, lag, a, b, warm[0])
            if got[3]:
                warm[0] = got[4]
                return got[:3]
        got = _Series._fixed_point(pl, P, s, lag, a, b, None)
        if warm is not None and got[3]:
            warm[:] = [got[4]]
        return got[:3]

    @staticmethod
    def _fixed_point(pl, P, s, lag, a, b, start, stall=True):
        """:meth:`_nonlinear` from ``start`` (or cold): (Yk, frac, U, converged, state); ``stall``: end
        when the fraction's steps stop shrinking below 1e-6 (rounding) rather than after 40 of them."""
        c_q = pl.quadratic_drag
        drag = 0.0 if c_q > 0 or not np.isfinite(pl.Td) else 1.0 / pl.Td
        if start is None:
            frac, r_hat, lin = -b / (a - b), np.zeros(N_SERIES, complex), None
        else:
            frac, r_hat, lin = start
        # the velocity's half spectrum, scaled for the inverse FFT: one buffer whose harmonics each step
        # overwrites (the same numbers as concatenating zeros around them; issue 39's CPU)
        spec = np.zeros(_M // 2 + 1, complex)
        converged, last_step = False, math.inf
        force = _Force(pl, P, s, a, b)  # what does not depend on the fraction, once
        for _ in range(40):
            if not (0.0 < frac < 1.0):
                return None, frac, None, False, None
            got = force.at(frac)
            if got is None:
                return None, frac, None, False, None
            Fk, F0, dF0, U = got
            Pk = Fk * lag
            target, settled = 0.0, True
            if c_q > 0:
                if lin is None:
                    # the velocity's amplitude without drag sets the describing-function damping
                    V0 = np.abs(2.0 * pl.K * Pk[0] / s[0])
                    lin = 8.0 * c_q * V0 / (3.0 * math.pi)
                Vk = (pl.K * Pk - r_hat) / (s + lin)
                spec[1:N_SERIES + 1] = Vk * _M
                v = np.fft.irfft(spec, _M)
                R = np.fft.rfft(c_q * v * np.abs(v) - lin * v) / _M
                r_new = R[1:N_SERIES + 1]
                settled = np.abs(r_new - r_hat).max() <= 1e-12 * (np.abs(Vk).max() * (lin + 1e-300) + 1e-300)
                r_hat = r_new
                target = R[0].real / pl.K  # the mean drag is balanced by a mean force
            step = (F0 - target) / dF0
            # (a small step that no longer shrinks is rounding: a large hover thrust F leaves steps of
            # +-5e-12 (F 5e3) to +-5e-9 (F 5e6) forever, which took 40 iterations to end anywhere in that band)
            if settled and (abs(step) < 1e-12 or (stall and last_step <= abs(step) < 1e-6)):
                converged = True
                break  # (the series above belong to this frac)
            frac -= step
            last_step = abs(step)
        state = (frac, r_hat, lin)
        if c_q > 0:
            return 2.0 * (pl.K * Pk - r_hat) / ((s + lin) * s), frac, U, converged, state
        return 2.0 * pl.K * Pk / (s * (s + drag)), frac, U, converged, state

    def grid(self) -> np.ndarray:
        X = np.zeros(_M // 2 + 1, complex)
        X[1:N_SERIES + 1] = self.Yk
        return np.fft.irfft(X, _M) * (_M / 2.0)

    def at(self, t: float) -> float:
        return float(np.real(np.exp(1j * self.k * self.w * t) @ self.Yk))

    def at_high(self) -> float:
        """The output at the switch to the low level, t = H: :meth:`at` with the input series' own
        exp(-j k w H) conjugated (the same numbers: one complex exponential of the series fewer)."""
        if self.phase is None or self.phase[0] != self.H:
            return self.at(self.H)
        return float(np.real(np.conj(self.phase[1]) @ self.Yk))


def _refined(yg: np.ndarray, i: int, sign: float) -> float:
    """Extremum near grid index i (parabola through three points)."""
    n = yg.size
    y0, y1, y2 = yg[(i - 1) % n], yg[i], yg[(i + 1) % n]
    den = y0 - 2.0 * y1 + y2
    if den * sign >= 0:
        return float(y1)
    return float(y1 - 0.125 * (y2 - y0) ** 2 / den)


def _conditions(pl: CyclePlant, P: float, beta_up: float, beta_dn: float, warm: list | None = None):
    """(residual of the -h -> +h condition, the constant, the series) at period P (``warm``: see
    :meth:`_Series._nonlinear`)."""
    ser = _Series(pl, P, warm)
    if not ser.ok:
        return None
    yg = ser.grid()
    iH = int(round(ser.H / P * _M))
    iH = min(max(iH, 1), _M - 1)
    hi, lo = yg[: iH + 1], yg[iH:]
    m1 = _refined(yg, int(np.argmin(hi)), -1.0)
    M2 = _refined(yg, iH + int(np.argmax(lo)), 1.0)
    yH = ser.at_high()
    y0 = float(np.sum(ser.Yk.real))
    c = (-beta_dn * m1 - yH) / (1.0 + beta_dn)
    f = c * (1.0 + beta_up) + beta_up * M2 + y0
    return f, c, ser


def periodic_solution(pl: CyclePlant, beta_up: float, beta_dn: float, period_guess: float,
                      *, rtol: float = 1e-10, slope_guess: float | None = None,
                      state_guess: tuple | None = None) -> PeriodicSolution | None:
    """The periodic MRFT cycle of ``pl`` near ``period_guess`` [s]; None when there is none.

    ``beta_up`` / ``beta_dn``: the relay's switching levels at the -h -> +h and +h -> -h switches
    (the effective ones a recording achieved), as in
    :func:`mrftcli.diagnose.limit_cycles.run_relay`. ``slope_guess``: dF/dP of the switching
    residual at a nearby solution (``PeriodicSolution.slope``), which makes the first step Newton's.
    ``state_guess``: a nearby solution's nonlinear fixed point (``PeriodicSolution.state``), its start;
    each period tried starts from the last one's (the cycle found does not depend on the start, to
    the fixed point's 1e-12 tolerance; it only takes fewer steps: issue 39's speed).

    Examples
    --------
    The symmetric linear loop against the exact LPRS period of :mod:`mrftcli.mrft.lprs`:

    >>> from mrftcli.mrft.lprs import mrft_limit_cycle
    >>> from mrftcli.mrft.model import LoopModel
    >>> m = LoopModel(Tp=0.0422, Td=2.669, tau=0.0464, K=15.0)
    >>> sol = periodic_solution(CyclePlant(m.Tp, m.Td, m.tau, m.K, 0.1, -0.1), -0.4, -0.4, 1.0)
    >>> lc = mrft_limit_cycle(m, -0.4, h=0.1)
    >>> abs(sol.period * lc.frequency_hz - 1.0) < 1e-6
    True
    """

    warm: list = [] if state_guess is None else [state_guess]

    last: list = [None, None]  # the last period evaluated and its conditions

    def f(P):
        got = _conditions(pl, P, beta_up, beta_dn, warm)
        last[:] = [P, got]
        return np.nan if got is None else got[0]

    P0 = float(period_guess)
    f0 = f(P0)
    if not np.isfinite(f0):
        return None
    # secant steps from the guess (a warm start is within a fraction of a percent: 3-4 steps), keeping
    # the last sign change as a bracket for brentq if the secant wanders
    P1 = P0 * 1.001 if not slope_guess else P0 - f0 / slope_guess
    if not (0.5 * P0 < P1 < 2.0 * P0) or P1 == P0:
        P1 = P0 * 1.001
    f1 = f(P1)
    lo = hi = None
    P = None
    last_slope = 0.0
    for _ in range(40):
        if not np.isfinite(f1):
            P1 = 0.5 * (P0 + P1)
            f1 = f(P1)
            continue
        if f1 == 0.0:
            P = P1
            break
        if np.sign(f1) != np.sign(f0):
            lo, hi = sorted((P0, P1))
        slope = (f1 - f0) / (P1 - P0)
        if slope == 0:
            return None
        last_slope = slope
        step = -f1 / slope
        if abs(step) <= rtol * P1:
            P = P1  # within rtol of the root: its series, just evaluated, is the solution's
            break
        # the secant converges superlinearly: the error left after this step is of the order of the
        # step times the one before it over P, so once that product is far below rtol the step ends it
        # (one evaluation of the series fewer per solution than waiting for a step below rtol P;
        # issue 39's speed)
        if f1 == f0 or abs(step) * abs(P1 - P0) <= _SECANT_MARGIN * rtol * P1 * P1:
            P = P1 + step
            break
        step = math.copysign(min(abs(step), 0.3 * P1), step)
        P2 = P1 + step
        if lo is not None and hi is not None and not (lo < P2 < hi):
            break
        if P2 <= 0:
            return None
        P0, f0, P1 = P1, f1, P2
        f1 = f(P1)
    if P is None:
        if lo is None:
            return None
        try:
            P = brentq(f, lo, hi, rtol=rtol, xtol=rtol * lo)
        except ValueError:
            return None
    return _solution(pl, P, beta_up, beta_dn, warm, last_slope, last[1] if last[0] == P else None)


def cycle_at_period(pl: CyclePlant, P: float, beta_up: float, beta_dn: float,
                    state: tuple | None = None) -> tuple[float, PeriodicSolution] | None:
    """The cycle of ``pl`` at the period P [s] whether or not P is its period: the residual of the
    -h -> +h switching condition there [output units] (zero at a periodic solution) and the series
    (``state``: a nearby solution's nonlinear fixed point, as in :func:`periodic_solution`); None when
    there is none. A Jacobian column's cycle at its point's period (issue 39)."""
    warm: list = [] if state is None else [state]
    got = _conditions(pl, P, beta_up, beta_dn, warm)
    if got is None:
        return None
    sol = _solution(pl, P, beta_up, beta_dn, warm, 0.0, got)
    return None if sol is None else (float(got[0]), sol)


def _solution(pl: CyclePlant, P: float, beta_up: float, beta_dn: float, warm: list, slope: float,
              got: tuple | None = None) -> PeriodicSolution | None:
    """The cycle at period P [s] (its conditions ``got`` when evaluated there already)."""
    got = got or _conditions(pl, P, beta_up, beta_dn, warm)
    if got is None:
        return None
    _, c, ser = got
    Y = np.concatenate([[c + 0j], ser.Yk])
    U = np.concatenate([[0j], ser.U])
    return PeriodicSolution(period=P, high=ser.H, Y=Y, U=U, slope=slope, state=warm[0] if warm else None)


def replace_levels(pl: CyclePlant, a: float, b: float) -> CyclePlant:
    """``pl`` with other input levels (the rotor-speed targets of thrust rectification); a slew keeps
    its ramp time."""
    from dataclasses import replace

    rate = pl.rate_limit * (a - b) / (pl.level_high - pl.level_low) if pl.rate_limit > 0 else 0.0
    return replace(pl, level_high=a, level_low=b, rate_limit=rate)
