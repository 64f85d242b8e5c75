"""A clean process plant under a sampled relay is kept clean by ``diagnose --model`` (issues 36, 39).

The oracle is tests/process_sim.py (an exact zero-order-hold loop sharing no code with mrftcli): the
plant is the family diagnosed, so nothing may be located. Users fly MRFT tests of 10-14 s at a few
betas at 20-500 Hz; two ways the check called such flights "unexplained" before:

* an effective MRFT's beta is read as the switching level over the *smooth* waveform's amplitude
  (eight harmonics, which round a first-order plant's kinked peak off), so the model's cycle was
  predicted under a beta too large by the same ratio: 1.7-2.8 % fast, 4-7 sigma, on every clean FOPDT;
* a relay deciding on samples settles on one of several whole-sample orbits; at 20 Hz (20-32
  samples a cycle) they are 5-10 % apart, and the check compared the measurement with the band's
  centre alone (5.3 sigma).

An effect is still named: a second-order plant diagnosed as FOPDT gets its second lag.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate  # noqa: E402

from mrftcli.diagnose import DiagnosisResult, diagnose  # noqa: E402
from mrftcli.io.logtypes import FlightLog, Signal  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402

SOPDT = dict(K=2.0, T1=0.8, T2=0.25, tau=0.15)


def _mrft(family: str, params: dict[str, float], rate_hz: float) -> FlightLog:
    """Two MRFT tests of 12 s (beta -0.2, -0.45), noise 0.003 (about 1 % of the amplitude)."""
    windows = [Window("mrft", 1.0, -1.0, beta=b, duration=12.0, rest=3.0) for b in (-0.2, -0.45)]
    t, u, y = simulate(family, params, windows, rate_hz, 0.003, seed=2, start=0.02)
    return FlightLog(path=f"{family}.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y))


def _assert_clean(result: DiagnosisResult, name: str) -> None:
    assert result.summary == f"consistent with {name} within the tests' scatter", result.summary
    assert not result.located and not result.found
    for check in result.checks:
        assert check.frequency_z is not None and abs(check.frequency_z) < 3
        assert check.amplitude_z is not None and abs(check.amplitude_z) < 3
        assert all(b.ratio < 3 for b in check.all_bands)


def test_clean_fopdt_under_a_50_hz_mrft_is_consistent():
    result = diagnose(_mrft("fopdt", dict(K=2.0, T=1.0, tau=0.3), 50.0), family_model("fopdt"))
    _assert_clean(result, "FOPDT")
    # the held-out cycle within 1.5 % (the 50 Hz loop's orbits are 2-4 % apart): the effective beta
    # read on the smooth waveform no longer predicts the cycle 2 % fast
    assert all(abs(c.frequency_error or 1.0) < 0.015 for c in result.checks)


def test_clean_fopdt_under_a_20_hz_hysteresis_relay_is_consistent():
    # batch's fleet recording: 20 Hz, two hysteresis relays, 20 s tests; its orbits are 20-30 samples
    windows = [Window("hysteresis", 1.0, -1.0, eps=e, duration=20.0) for e in (0.05, 0.3)]
    t, u, y = simulate("fopdt", dict(K=1.5, T=0.8, tau=0.25), windows, 20.0, 0.01, seed=1)
    result = diagnose(FlightLog(path="b.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y)),
                      family_model("fopdt"))
    _assert_clean(result, "FOPDT")


@pytest.fixture(scope="module")
def sopdt_flight() -> FlightLog:
    return _mrft("sopdt", SOPDT, 100.0)


def test_clean_sopdt_under_a_100_hz_mrft_is_consistent(sopdt_flight):
    _assert_clean(diagnose(sopdt_flight, family_model("sopdt")), "SOPDT")


def test_the_second_lag_a_fopdt_leaves_out_is_still_named(sopdt_flight):
    result = diagnose(sopdt_flight, family_model("fopdt"))
    assert result.summary.startswith("found: sensor_lag") and not result.consistent
    (lag,) = result.effects
    assert sorted([lag.value, lag.refit["T"]]) == pytest.approx([SOPDT["T2"], SOPDT["T1"]], rel=0.25)
    assert lag.held_out_after < 0.5 * lag.held_out_before
