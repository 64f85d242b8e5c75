"""Issue 22: the per-cycle harmonics of :func:`mrftcli.analyze.smooth_cycle.cycle_fits` against closed forms.

An IPDT under an ideal relay outputs a triangle, which has every odd harmonic. A fit of one cycle with a
free line plus harmonics 1..H hands the harmonics above H back to 1..H through the line (-0.77 % at the
fundamental with H = 3: K read 1 % low); the fit must not.

Oracle: the triangle's Fourier series, ``y = sum_{m odd} 4 A / (pi m)^2 e^{j m (Omega x - phi)}`` over
all m of both signs, and the exact identity for N uniform samples a period at ``x_n = (n + delta) P / N``:
the least-squares harmonic k (k < N / 2) is ``Y_k = 2 sum_{m = k mod N} c_m e^{j 2 pi (m - k) delta / N}``
(the aliases a sampled signal cannot tell from harmonic k). Summed here over 2 * 10^4 aliases; no code
shared with mrftcli.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from mrftcli.analyze.smooth_cycle import cycle_fits


def triangle(x: np.ndarray, period: float, amplitude: float, phase_peak: float) -> np.ndarray:
    """A triangle wave of half peak-to-peak ``amplitude``, at +amplitude where x / P = ``phase_peak`` (mod 1)."""
    u = np.mod(x / period - phase_peak, 1.0)  # 0 at the peak
    return amplitude * (1.0 - 4.0 * np.minimum(u, 1.0 - u))


def sampled_triangle_harmonic(k: int, n_per_period: int, delta: float, amplitude: float, phase_peak: float,
                              n_aliases: int = 10_000) -> complex:
    """Y_k of the triangle sampled N times a period at offset ``delta`` (module docstring)."""
    m = k + n_per_period * np.arange(-n_aliases, n_aliases + 1)
    c = np.where(m % 2 == 1, 4 * amplitude / (math.pi * m) ** 2, 0.0) * np.exp(-2j * math.pi * m * phase_peak)
    return complex(2 * np.sum(c * np.exp(2j * math.pi * (m - k) * delta / n_per_period)))


def recording(n_per_period: int, delta: float, drift: float, n_cycles: int = 6, period: float = 1.3,
              amplitude: float = 2.0, phase_peak: float = 0.37) -> tuple[SimpleNamespace, SimpleNamespace]:
    """A flight and a test holding ``n_cycles`` triangle cycles on a ramp of ``drift`` [units / s]."""
    t0 = 10.0
    n = np.arange(n_cycles * n_per_period)
    t = t0 + (n + delta) * period / n_per_period
    y = triangle(t - t0, period, amplitude, phase_peak) + drift * (t - t0) + 0.5
    cycles = tuple(SimpleNamespace(t_start=t0 + i * period, t_switch=t0 + (i + 0.5) * period,
                                   t_end=t0 + (i + 1) * period, flags=()) for i in range(n_cycles))
    flight = SimpleNamespace(output=SimpleNamespace(t=t, values=y))
    return flight, SimpleNamespace(loop_sign=1, stable=cycles)


@pytest.mark.parametrize("n_per_period", [16, 23, 40])
@pytest.mark.parametrize("drift", [0.0, 0.9])
def test_triangle_harmonics_exact(n_per_period: int, drift: float) -> None:
    """Every cycle's harmonics are the sampled triangle's to 1e-3 relative, flat or on a ramp."""
    delta = 0.29
    flight, test = recording(n_per_period, delta, drift)
    fits = cycle_fits(flight, test)  # type: ignore[arg-type]  # duck-typed records: only times and values used
    assert len(fits) == len(test.stable)
    H = min(8, (n_per_period - 2) // 4)
    expected = np.array([sampled_triangle_harmonic(k, n_per_period, delta, 2.0, 0.37) for k in range(1, H + 1)])
    for f in fits:
        assert f.harmonics.size == H
        err = np.abs(f.harmonics - expected)
        odd = np.arange(1, H + 1) % 2 == 1
        assert np.all(err[odd] <= 1e-3 * np.abs(expected[odd])), (f.harmonics, expected)
        assert np.all(err[~odd] <= 1e-3 * abs(expected[0]))


def test_free_line_would_bias_the_fundamental() -> None:
    """The oracle tells the biased fit apart: a free line moves this fundamental by +1.6 % (H = 3)."""
    from mrftcli.mrft.harmonics import fit_harmonics

    P, N, delta = 1.3, 16, 0.29
    x = (np.arange(N) + delta) * P / N
    Y1 = fit_harmonics(x, triangle(x, P, 2.0, 0.37), P, 3).harmonics[0]
    exact = sampled_triangle_harmonic(1, N, delta, 2.0, 0.37)
    assert abs(abs(Y1) / abs(exact) - 1) > 5e-3
