"""Accuracy over 30 random plants simulated with the project's simulator (issue 4's acceptance).

200 Hz controller, sensor noise 0.5 mm (altitude) / 0.2 deg (roll, pitch), at least 8 stable cycles
per test; tests planned for 5 cm / 10 deg oscillations with the HEAR switching rule. Targets: tau
within 1 ms, K within 3 %, Td within 5 % where Td * Omega <= 5 and the true Td inside the reported
95 % interval where it is larger (the MRFT estimate's bootstrap interval, on every plant), and the
reported estimate's 95 % intervals (the waveform refinement's, issue 16) holding the truth on at least
90 % of the plants. The truth is the plant each flight was simulated with.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
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
def test_thirty_random_plants(sweep_size):
    failures, tau_errors, covered = [], [], {"tau": 0, "K": 0, "Td": 0}
    plants = list(sweep_plants(sweep_size(30, 12), seed=0))  # 12 in CI; --full-sweeps: the 30
    for k, loop, Tp, Td, tau, K in plants:
        betas = (-0.4, -0.7) if loop == "altitude" else (-0.5, -0.8)
        sf = simulate_paper_flight(Tp, Td, tau, K, betas, loop=loop, cycles=12.0, seed=k)
        r = analyze_flight(flight_from_simulated(sf), soiptd_model(Tp))
        # no false rejection by the limit-cycle validity check
        assert not r.rejected and len(r.tests) == len(betas), (k, r.rejection_reasons)
        assert all(t.validity.ok for t in r.tests), (k, [t.validity.reasons for t in r.tests])
        assert all(t.n_stable >= 8 for t in r.tests), (k, [t.n_stable for t in r.tests])
        td_omega = max(r.model.Td * 2 * np.pi * t.frequency_hz_mean for t in r.tests)
        tau_errors.append(r.tau.value - tau)
        # the MRFT estimate's (bootstrap) intervals hold the truth on every plant, as before the refinement
        mrft = r.parameters_mrft
        ok_tau = mrft["tau"].ci95_low <= tau <= mrft["tau"].ci95_high
        ok_K = abs(r.K.value / K - 1) <= 0.03
        ok_Td = (abs(r.Td.value / Td - 1) <= 0.05 if td_omega <= 5
                 else mrft["Td"].ci95_low <= Td <= mrft["Td"].ci95_high)
        if not (ok_tau and ok_K and ok_Td):
            failures.append((k, loop, f"tau err {1e3 * (r.tau.value - tau):+.2f} ms", f"K err {100 * (r.K.value / K - 1):+.2f} %",
                             f"Td {r.Td.value:.3f} [{mrft['Td'].ci95_low:.3f}, {mrft['Td'].ci95_high:.3f}] true {Td:.3f}",
                             f"Td*Omega {td_omega:.1f}"))
        # the reported (refined) estimate's 95 % intervals: honest, so judged by their coverage below
        for name, true in (("tau", tau), ("K", K), ("Td", Td)):
            est = getattr(r, name)
            covered[name] += bool(est.ci95_low <= true <= est.ci95_high)
    assert not failures, failures
    # issue 16: the 95 % interval holds the truth in at least 90 % of the sweep (27 of 30)
    assert all(n >= 0.9 * len(plants) for n in covered.values()), covered
    err_ms = np.abs(np.array(tau_errors)) * 1e3
    # The target, for every plant. (With the UFM slices alone, the paper's method, plant 3 -
    # Tp 0.079 s, Td 0.22 s, tau 76 ms - missed it by 2.5 ms through the noise of the measured
    # switching levels; the weighted harmonic-phase constraint removes that: docs/benchmarks/analyze.md.)
    assert np.all(err_ms <= 1.0), np.round(err_ms, 2)
    assert np.sqrt(np.mean(err_ms**2)) < 0.5
