"""``watch --model NAME``: a process plant identified while its recording grows (the one ``watch``, a family model).

Oracle: relay tests simulated by tests/process_sim.py (independent of mrftcli: the plant from its
transfer function's polynomials, stepped exactly), whose truth the final estimate must recover; and
``analyze_flight`` on the finished file, which the final update must equal.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from cli_helpers import LiveWriter, run_cli as _cli  # noqa: E402
from process_sim import Window, simulate, write_csv  # noqa: E402

from mrftcli.analyze import analyze_flight  # noqa: E402
from mrftcli.errors import InputError  # noqa: E402
from mrftcli.io import ReadOptions, read_flight  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402
from mrftcli.watch import EstimateUpdate, TestUpdate, WatchEnd, WatchOptions, watch  # noqa: E402

TRUTH = dict(K=2.0, T=0.5, tau=0.1)
READ = ReadOptions(command_topic="u_relay", output_topic="y_output")
#: two relay phases (an eq. (2) user would say two betas): a biased relay with a small hysteresis, then a
#: symmetric one with a larger hysteresis
WINDOWS = [Window("hysteresis", 1.5, -0.5, eps=0.05, duration=8.0, rest=2.0),
           Window("hysteresis", 1.0, -1.0, eps=0.25, duration=8.0, rest=2.0)]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    t, u, y = simulate("fopdt", TRUTH, WINDOWS, 100.0, 0.01, seed=3)
    path = tmp_path_factory.mktemp("watch_model") / "fopdt.csv"
    write_csv(str(path), t, u, y)
    return path


def test_live_estimates_arrive_before_the_end_and_the_final_is_analyze_model(recording, tmp_path):
    w = LiveWriter(recording.read_bytes(), tmp_path / "live.csv", 9001)  # slices end in the middle of rows
    got = [(u, w.pos) for u in watch(w.dst, family_model("fopdt"), read=READ,
                                           options=WatchOptions(idle=0.3, poll=0.1), sleep=w.sleep, clock=w.clock)]
    tests = [u for u, _ in got if isinstance(u, TestUpdate)]
    assert {u.number for u in tests} == {1, 2}
    first = tests[0]
    assert first.relay.kind == "hysteresis" and first.relay.source == "inferred"
    assert (first.relay.high, first.relay.low) == pytest.approx((1.5, -0.5))
    assert any("bias" in n for n in first.notes)  # the biased relay's assumption, stated on its line
    live = [(u, pos) for u, pos in got if isinstance(u, EstimateUpdate) and not u.final]
    assert live and live[0][1] < len(w.data)  # an estimate while the file was still being written
    final = [u for u, _ in got if isinstance(u, EstimateUpdate) and u.final]
    assert len(final) == 1 and final[0].analysis is not None
    ref = analyze_flight(read_flight(recording, READ, echo_warnings=False), family_model("fopdt"))
    assert final[0].analysis.to_json() == {**ref.to_json(), "path": final[0].analysis.path}
    last_live = {e.name: e.value for e in live[-1][0].parameters}
    for e in final[0].parameters:  # the last live fit used the same cycles, less a possible last one
        assert last_live[e.name] == pytest.approx(e.value, rel=0.05)
    end = got[-1][0]
    assert isinstance(end, WatchEnd) and end.reason == "idle" and end.exit_code == 0


def test_one_test_names_what_it_cannot_determine_instead_of_a_number(recording, tmp_path):
    # the first window alone, fitted with two lags: three points (harmonics 1, 3, 5 of one relay
    # phase) do not pin the second lag down; the update says so, and the CLI line gives it no number
    from mrftcli.cli.model_options import parameter_display
    from mrftcli.cli.watch import _line

    data = recording.read_bytes()
    cut = tmp_path / "one.csv"
    cut.write_bytes(data[:data.index(b"\n", len(data) // 2) + 1])  # the first window and its rest
    got = list(watch(cut, family_model("sopdt"), read=READ, options=WatchOptions(idle=0.2, poll=0.1),
                           sleep=lambda dt: None, clock=iter(range(100)).__next__))
    live = [u for u in got if isinstance(u, EstimateUpdate) and not u.final]
    assert live and live[-1].undetermined and "another phase" in live[-1].advice
    shown, _, refusal = _line(live[-1], "m", parameter_display("family", "altitude")).partition("(tests")
    assert "so far" in refusal and "nan" not in shown.lower()
    assert all(f"{name} " not in shown for name in live[-1].undetermined)
    assert "K " in shown  # what one test does determine is given


def test_updates_round_trip_through_json_and_refuse_another_version(recording):
    got = list(watch(recording, family_model("fopdt"), read=READ, options=WatchOptions(idle=0.1, poll=0.1),
                           sleep=lambda dt: None, clock=iter(range(100)).__next__))
    for u in got:
        if isinstance(u, (TestUpdate, EstimateUpdate)):
            data = json.loads(json.dumps(u.to_json()))
            assert type(u).from_json(data).to_json() == u.to_json()
    estimate = next(u for u in got if isinstance(u, EstimateUpdate))
    with pytest.raises(InputError, match="schema_version"):
        EstimateUpdate.from_json({**estimate.to_json(), "schema_version": 99})
    with pytest.raises(InputError, match="watch test update"):
        TestUpdate.from_json({"schema_version": 2, "number": 1})


def test_a_stated_relay_reaches_each_test_and_eq2_refuses_one(recording):
    from mrftcli.analyze import RelayOptions
    from mrftcli.mrft.model import soiptd_model

    stated = WatchOptions(idle=0.1, poll=0.1, relay=RelayOptions("hysteresis", None, 0.04))
    got = list(watch(recording, family_model("fopdt"), read=READ, options=stated, sleep=lambda dt: None,
                     clock=iter(range(100)).__next__))
    tests = [u for u in got if isinstance(u, TestUpdate)]
    assert tests and all(u.relay.source == "stated" and u.relay.eps == 0.04 for u in tests)
    with pytest.raises(InputError, match="process model"):
        watch(recording, soiptd_model(0.0422), read=READ, options=stated)
    with pytest.raises(InputError, match="unknown relay"):
        WatchOptions(relay=RelayOptions("bang-bang"))


def test_cli_model_options_refused_where_they_do_not_apply(capsys, recording):
    code, _, err = _cli(capsys, "watch", str(recording), "--model", "fopdt", "--tp", "0.04")
    assert code == 2 and "--param" in err and "Traceback" not in err
    code, _, err = _cli(capsys, "watch", str(recording), "--param", "K=2")  # eq. (2) with a process option
    assert code == 2 and "--tp" in err


def test_cli_final_estimate_recovers_the_simulated_plant(capsys, recording):
    argv = ["watch", str(recording), "--model", "fopdt", "--command-topic", "u_relay", "--output-topic", "y_output",
            "--idle", "0.1"]
    code, out, err = _cli(capsys, *argv, "--jsonl")
    assert code == 0 and err == "", err
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["kind"] for r in rows[-2:]] == ["estimate", "end"] and rows[-2]["final"] is True
    assert rows[0]["kind"] == "test" and rows[0]["relay"]["kind"] == "hysteresis"
    params = rows[-2]["parameters"]
    for name, value in TRUTH.items():
        assert params[name]["value"] == pytest.approx(value, rel=0.05), name
        assert params[name]["ci95_low"] <= value <= params[name]["ci95_high"], name
    # the text: the structure first, each test with its relay as inferred, units on every number
    code, out, _ = _cli(capsys, *argv)
    lines = out.splitlines()
    assert code == 0 and lines[0].startswith("model fopdt: G(s) = K e^{-tau s}")
    tests = [line for line in lines if line.startswith("test ")]
    assert tests and all("relay: hysteresis" in t and "(inferred)" in t and "output units" in t for t in tests)
    final = next(line for line in lines if line.startswith("final"))
    assert "K " in final and " output / command" in final and "tau " in final and " s " in final and "±" in final
    assert sum(line.startswith("held-out test") for line in lines) == 2


def test_cli_model_file_is_the_declared_structure(capsys, recording, tmp_path):
    spec = tmp_path / "fopdt.toml"
    spec.write_text('transfer_function = "K*exp(-tau*s)/(T*s+1)"\n[parameters]\nK = {range = [0.1, 10]}\n'
                    'T = {range = [0.01, 10]}\ntau = {value = 0.1}\n')
    code, out, err = _cli(capsys, "watch", str(recording), "--model-file", str(spec), "--command-topic", "u_relay",
                          "--output-topic", "y_output", "--idle", "0.1", "--jsonl")
    assert code == 0, err
    final = [json.loads(line) for line in out.splitlines()][-2]
    assert final["model"] == "declared" and final["final"] is True
    assert final["parameters"]["tau"]["known"] is True  # the file's known value (the paper's set E)
    for name in ("K", "T"):
        assert final["parameters"][name]["value"] == pytest.approx(TRUTH[name], rel=0.05), name
