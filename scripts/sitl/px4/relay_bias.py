"""Each altitude test's relay bias against the loop's trim, from a PX4 ULog: the stable cycles' half-period
asymmetry (T_high - T_low) / (T_high + T_low) (-b/h for a relay biased by b on an integrator), PX4's hover-thrust
estimate during the test (mean, range against h) and the command's mean over the test against it.

    python scripts/sitl/px4/relay_bias.py /work/sitl/px4_c3/px4_altitude.ulg /work/sitl/px4_c3/px4_altitude_20ms.ulg

Issue 42's h 0.05 +20 ms pair (docs/benchmarks/sitl.md): a bias b lengthens an integrator's relay cycle by
1 / (1 - (b/h)^2), so it matters where h is small; the pair model (and eq. (2)) takes every cycle as symmetric.
"""

from __future__ import annotations

import sys

import numpy as np

from mrftcli.io import ReadOptions, open_log, read_flight
from mrftcli.segment import segment


def main(paths: list[str]) -> int:
    for path in paths:
        flight = read_flight(path, ReadOptions(loop="altitude"), echo_warnings=False)
        with open_log(path, None, echo_warnings=False) as src:
            t, d = src.read("hover_thrust_estimate", ["hover_thrust", "valid"])
        t, hover, ok = np.asarray(t, float), np.asarray(d["hover_thrust"], float), np.asarray(d["valid"]) > 0
        print(path)
        for test in segment(flight):
            hi = np.mean([c.half_period_high for c in test.stable])
            lo = np.mean([c.half_period_low for c in test.stable])
            asym = (hi - lo) / (hi + lo)
            h_est = hover[ok & (t >= test.t_start) & (t <= test.t_end)]
            c = flight.command
            centre = float(np.mean(c.values[(c.t >= test.t_start) & (c.t <= test.t_end)]))
            print(f"  beta {test.beta_nominal:+.2f} h {test.h:.3f}: {test.frequency_hz_mean:.3f} Hz over {test.n_stable} "
                  f"stable cycles; half-period asymmetry {asym * 100:+.1f} % (an integrator's period x "
                  f"{1 / (1 - asym ** 2):.4f}); hover estimate {h_est.mean():.4f} (range {np.ptp(h_est) / test.h * 100:.0f} % "
                  f"of h); command mean - hover estimate {(centre - h_est.mean()) / test.h * 100:+.0f} % of h")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
