"""Accuracy over 30 random plants simulated with the project's simulator (issue 4's acceptance).

200 Hz controller, sensor noise 0.5 mm (altitude) / 0.2 deg (roll, pitch), at least 8 stable cycles
per test; tests planned for 5 cm / 10 deg oscillations with the HEAR switching rule. Targets: tau
within 1 ms, K within 3 %, Td within 5 % where Td * Omega <= 5 and the true Td inside the reported
95 % interval where it is larger. The truth is the plant each flight was simulated with. The
estimator is the default one (UFM slices plus the weighted phase and amplitude constraints).
"""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.analyze import analyze_flight
from test_segment_support import flight_from_simulated, simulate_paper_flight


def sweep_plants(n: int, seed: int):
    rng = np.random.default_rng(seed)
    for k in range(n):
        loop = ("altitude", "roll", "pitch")[k % 3]
        Tp = float(np.exp(rng.uniform(np.log(0.02), np.log(0.1))))
        Td = float(np.exp(rng.uniform(np.log(0.2), np.log(3.0))))
        tau = float(rng.uniform(0.01, 0.1))
        K = float(np.exp(rng.uniform(np.log(0.5), np.log(20.0))))
        yield k, loop, Tp, Td, tau, K


@pytest.mark.slow
def test_thirty_random_plants():
    failures, tau_errors = [], []
    for k, loop, Tp, Td, tau, K in sweep_plants(30, seed=0):
        betas = (-0.4, -0.7) if loop == "altitude" else (-0.5, -0.8)
        sf = simulate_paper_flight(Tp, Td, tau, K, betas, loop=loop, cycles=12.0, seed=k)
        r = analyze_flight(flight_from_simulated(sf), Tp)
        # no false rejection by the limit-cycle validity check
        assert not r.rejected and len(r.tests) == len(betas), (k, r.rejection_reasons)
        assert all(t.validity.ok for t in r.tests), (k, [t.validity.reasons for t in r.tests])
        assert all(t.n_stable >= 8 for t in r.tests), (k, [t.n_stable for t in r.tests])
        td_omega = max(r.model.Td * 2 * np.pi * t.frequency_hz_mean for t in r.tests)
        tau_errors.append(r.tau.mean - tau)
        ok_tau = r.tau.ci95_low <= tau <= r.tau.ci95_high
        ok_K = abs(r.K.mean / K - 1) <= 0.03
        ok_Td = abs(r.Td.mean / Td - 1) <= 0.05 if td_omega <= 5 else r.Td.ci95_low <= Td <= r.Td.ci95_high
        if not (ok_tau and ok_K and ok_Td):
            failures.append((k, loop, f"tau err {1e3 * (r.tau.mean - tau):+.2f} ms", f"K err {100 * (r.K.mean / K - 1):+.2f} %",
                             f"Td {r.Td.mean:.3f} [{r.Td.ci95_low:.3f}, {r.Td.ci95_high:.3f}] true {Td:.3f}",
                             f"Td*Omega {td_omega:.1f}"))
    assert not failures, failures
    err_ms = np.abs(np.array(tau_errors)) * 1e3
    # The target, for every plant. (With the UFM slices alone, the paper's method, plant 3 -
    # Tp 0.079 s, Td 0.22 s, tau 76 ms - missed it by 2.5 ms through the noise of the measured
    # switching levels; the weighted harmonic-phase constraint removes that: docs/benchmarks/analyze.md.)
    assert np.all(err_ms <= 1.0), np.round(err_ms, 2)
    assert np.sqrt(np.mean(err_ms**2)) < 0.5
