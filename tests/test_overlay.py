"""The predicted output (mrftcli.mrft.waveform) and the results MCAP (analyze --mcap-out).

Oracles: the closed-form step response of eq. (2) (partial fractions), and the sample logs' truth
sidecars (the predicted output of the true model must leave the sensor noise as its residual).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_cli

from mrftcli.errors import InputError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.waveform import predict_output, predict_tests
from mrftcli.segment import segment


def _step_response(m: LoopModel, t, t_step, height):
    """y(t) for a command step of ``height`` at ``t_step`` from rest: 1/(s^2 (Tp s + 1)(Td s + 1))."""
    tp = np.maximum(np.asarray(t) - t_step - m.tau, 0.0)
    a, b = m.Td, m.Tp
    return height * m.K * m.Td * (tp - (a + b) + (a * a * np.exp(-tp / a) - b * b * np.exp(-tp / b)) / (a - b))


@pytest.mark.parametrize("tau, offset", [(0.0123, 0.0), (0.0464, 0.0017), (0.005, 0.0049), (0.02, 0.0)])
def test_prediction_is_the_exact_delayed_step_response(tau, offset):
    m = LoopModel(Tp=0.05, Td=2.0, tau=tau, K=1.5)
    t = np.arange(0.0, 3.0, 0.005)
    u = np.full(t.size, 0.1)
    u[0] = 0.0  # the step is at the second sample (0.005 s), at rest before
    to = t[:-1] + offset  # output times between the command samples
    p = predict_output(m, t, u, to, fit_initial=False, x0=[0, 0, 0])
    np.testing.assert_allclose(p.y, _step_response(m, to, 0.005, 0.1), atol=1e-9)


def test_bias_is_the_equilibrium_and_the_initial_state_is_fitted():
    m = LoopModel(Tp=0.04, Td=1.5, tau=0.03, K=20.0)
    t = np.arange(0.0, 4.0, 0.01)
    u = 0.5 + 0.05 * np.sign(np.sin(2 * np.pi * 1.1 * t))
    x0 = np.array([1.0, 0.2, -0.05])
    truth = predict_output(m, t, u, t, bias=0.5 + 0.003, fit_initial=False, x0=x0)  # a trim error of 0.003
    rng = np.random.default_rng(3)
    noisy = truth.y + 1e-4 * rng.standard_normal(t.size)
    fit = predict_output(m, t, u, t, bias=0.5, output=noisy)
    assert fit.input_offset == pytest.approx(-0.003, abs=2e-4)
    assert fit.rms == pytest.approx(1e-4, rel=0.15)


def test_bad_arguments_are_input_errors():
    m = LoopModel(Tp=0.04, Td=1.5, tau=0.03, K=20.0)
    with pytest.raises(InputError):
        predict_output(m, [0.0], [1.0], [0.0], fit_initial=False)
    with pytest.raises(InputError):
        predict_output(m, [0.0, 0.01, 0.02], [1.0, 1.0, 1.0], [0.0, 0.01])  # fit without an output


@pytest.mark.parametrize("name", ["design1_altitude.mcap", "design2_roll.mcap"])
def test_true_model_leaves_the_sensor_noise_as_residual(repo_root, name):
    path = repo_root / "sample_logs" / name
    truth = json.loads(path.with_name(name + ".truth.json").read_text())
    flight = read_flight(path, ReadOptions(loop=truth["loop"]))
    model = LoopModel(truth["Tp"], truth["Td"], truth["tau"], truth["K"])
    fits = predict_tests(model, segment(flight), flight.command.t, flight.command.values, flight.output.t,
                         flight.output.values)
    assert len(fits) == 2
    for fit in fits.values():
        assert fit.rms == pytest.approx(truth["noise_std"], rel=0.1)


def _fields(buf: bytes) -> list[tuple[int, object]]:
    """Protobuf wire format read by hand (an oracle sharing no code with foxglove-sdk): (field, value)."""
    out, i = [], 0

    def varint() -> int:
        nonlocal i
        v = shift = 0
        while True:
            b = buf[i]
            i += 1
            v |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                return v

    while i < len(buf):
        key = varint()
        if key & 7 == 0:
            out.append((key >> 3, varint()))
        else:  # length-delimited (the only other wire type foxglove.Event uses)
            n = varint()
            out.append((key >> 3, buf[i:i + n]))
            i += n
    return out


def _event(buf: bytes) -> dict:
    """foxglove.Event{1 start_time, 2 end_time: Timestamp{1 sec, 2 nsec}, 3 metadata: KeyValuePair{1, 2}}."""
    ev: dict = {3: []}
    for f, v in _fields(buf):
        if f in (1, 2):
            ev[f] = dict(_fields(v))
        elif f == 3:
            kv = dict(_fields(v))
            ev[3].append((kv[1].decode(), kv[2].decode()))
    return ev


def test_analyze_mcap_out_reads_back_and_fits_within_the_noise(repo_root, tmp_path, capsys):
    from mcap.reader import make_reader

    log = repo_root / "sample_logs" / "design1_altitude.mcap"
    truth = json.loads((repo_root / "sample_logs" / "design1_altitude.mcap.truth.json").read_text())
    out = tmp_path / "fit.mcap"
    code, _, err = run_cli(capsys, "analyze", str(log), "--tp", "0.0422", "--mcap-out", str(out))  # in this process
    assert code == 0, err
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        msgs = {}
        for _, channel, message in reader.iter_messages():
            data = _event(message.data) if channel.message_encoding == "protobuf" else json.loads(message.data)
            msgs.setdefault(channel.topic, []).append((message.log_time, data))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        schemas = {channel.topic: reader.get_summary().schemas[channel.schema_id].name
                   for channel in reader.get_summary().channels.values()}
        records = {channel.topic: reader.get_summary().schemas[channel.schema_id]
                   for channel in reader.get_summary().channels.values()}
        attachments = {a.name: (a.media_type, a.data) for a in reader.iter_attachments()}
    fit = msgs["/mrft_ident/fit"]
    t = np.array([m[0] for m in fit]) / 1e9
    resid = np.array([m[1]["residual"] for m in fit])
    # the log's own clock: inside the tests of the truth sidecar
    spans = [(x["t_start"], x["t_end"]) for x in truth["tests"]]
    assert all(any(a - 0.01 <= ti <= b + 0.01 for a, b in spans) for ti in t[:: 50])
    assert np.sqrt(np.mean(resid ** 2)) == pytest.approx(truth["noise_std"], rel=0.15)
    tests = [m[1] for m in msgs["/mrft_ident/tests"]]
    # a square pulse per test: a plot joining the points never draws a diagonal across a test
    assert [x["active"] for x in tests] == [0, 1, 1, 0, 0, 1, 1, 0]
    edges = [m[0] / 1e9 for m in msgs["/mrft_ident/tests"]]
    assert edges[0] == edges[1] and edges[2] == edges[3]
    # Foxglove marks the tests on its timeline: foxglove.Event, start and span of each test
    assert schemas["/mrft_ident/events"] == "foxglove.Event"
    # the current Foxglove schema, byte for byte the one the maintained package ships (issue 37)
    from foxglove.messages import Event

    shipped = Event.get_schema()
    rec = records["/mrft_ident/events"]
    assert (rec.name, rec.encoding, rec.data) == (shipped.name, shipped.encoding, bytes(shipped.data))
    assert b"start_time" in rec.data and b"end_time" in rec.data and b"KeyValuePair" in rec.data
    events = [m[1] for m in msgs["/mrft_ident/events"]]
    assert len(events) == 2
    for ev, x in zip(events, truth["tests"]):
        start, end = ev[1][1] + ev[1].get(2, 0) / 1e9, ev[2][1] + ev[2].get(2, 0) / 1e9
        assert x["t_start"] - 0.5 <= start < end <= x["t_end"] + 0.5
        assert {k for k, _ in ev[3]} >= {"test", "beta", "h", "frequency_hz"}
    # the analysis rides along and reads back as the record analyze --json writes
    from mrftcli.analyze import AnalysisResult

    media, data = attachments["analysis.json"]
    assert media == "application/json"
    back = AnalysisResult.from_json(json.loads(data))
    assert back.tau.value == pytest.approx(msgs["/mrft_ident/parameters"][0][1]["tau"], rel=1e-9)
    assert [round(x["beta_nominal"], 3) for x in tests[::4]] == [-0.4, -0.7]
    params = msgs["/mrft_ident/parameters"][0][1]
    assert params["tau"] == pytest.approx(truth["tau"], abs=1e-3)
    assert "mrft_ident.test.2" in meta and meta["mrft_ident"]["loop"] == "altitude"


def test_mcap_out_path_is_checked_before_the_work(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("a file, not a folder")
    code, _, err = run_cli(capsys, "analyze", "no-such-log.mcap", "--tp", "0.04",  # in this process
                           "--mcap-out", str(tmp_path / "notes.txt" / "fit.mcap"))  # a missing folder is created
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("error: --mcap-out") and "is not a folder" in err
