"""Issue 35, part A: no text from a file or an option runs as code; model, JSON and YAML sizes bounded.

Every hostile input is generated here. Each is given to the CLI in this process (tests/cli_helpers.py):
it must give a one-line error and a non-zero exit, no traceback, and create no file (the payloads try
to create a marker file). Legitimate transfer functions must still give the coefficients of their
closed form, written out by hand here (numpy's polymul, no code shared with the parser).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.model_file import declared_model, load_model_file, parse_model_spec

sys.path.insert(0, str(Path(__file__).parent))
from cli_helpers import run_cli  # noqa: E402

MARKER = "pwned_marker"


def _payloads(marker: Path) -> list[str]:
    """Texts that would run ``touch MARKER`` (or read attributes on the way to it) if evaluated."""
    shell = f"touch {marker}"
    quoted = "'" + shell + "'"
    return [
        # the sympy payload style: a string handed to exp() (sympify evaluates strings), built from names
        f"K*exp(os.system({quoted}))/(T*s + 1)",
        f"K*exp({quoted})/(T*s + 1)",
        "K*exp(system.name + os.name)/(T*s + 1)",
        # attribute access without any dunder
        "K*exp(-tau*s)/(T*s + 1).func(s)",
        "K.subs(T)/(T*s + 1)",
        "(T*s + 1).as_base_exp",
        # calls of other names, lambdas, comprehensions, subscripts, conditionals, walrus, f-strings
        f"K*__import__('os').system({quoted})/(T*s + 1)",
        "K*getattr(T, 'func')/(T*s + 1)",
        f"K*exec({quoted})/(T*s + 1)",
        "K*(lambda: 1)()/(T*s + 1)",
        "K*sum([T for T in (1, 2)])/(T*s + 1)",
        "K*{T: 1 for T in (1,)}[1]/(T*s + 1)",
        "K*[1, 2][0]/(T*s + 1)",
        "K*(1 if T else 2)/(T*s + 1)",
        "K*(x := 2)/(T*s + 1)",
        "K*f'{T}'/(T*s + 1)",
        "K*b'x'/(T*s + 1)",
        "K*(T < 1)/(T*s + 1)",
        "K*(T and 1)/(T*s + 1)",
        "K*1j/(T*s + 1)",
        "K*True/(T*s + 1)",
        "K*(T @ T)/(T*s + 1)",
        "K*(T // 2)/(T*s + 1)",
        "K*(T % 2)/(T*s + 1)",
        "K*~T/(T*s + 1)",
        "K*exp(s, s)/(T*s + 1)",
        "K*exp(x=s)/(T*s + 1)",
        "K*exp(*s)/(T*s + 1)",
        "K/(T*s + 1); import os",
        "K/(T*s + 1)\nimport os",
        "K/(T*s + 1)\x00",
        "K*Q/(T*s + 1)",  # an undeclared name
    ]


def _limit_texts() -> list[str]:
    return [
        "K/(s**10**10 + 1)",
        "K/((T*s + 1)**100000)",
        "K/(T*s + 1)**21",
        "K/(T*s + 1)**2.5",
        "K/(T*s + 1)**-1",
        "K/(T*s + 1)**T",
        "K/(" + "(" * 500 + "T*s + 1" + ")" * 500 + ")",
        "K/(" + "-" * 3000 + "T*s + 1)",
        "K/(" + " + ".join(["T*s"] * 30000) + " + 1)",  # 30,000 terms
        "K/(" + " + ".join(["T*s"] * 300) + " + 1)",  # within the text limit, above the node limit
        "K/(" + "*".join(["(T*s + 1)"] * 200) + ")",  # 200th order
        "K/((T*s + 1)**20*(T*s + 1))",  # 21st order
        "K/(T*s + a + b + c + d + e + f)**10",  # would expand to thousands of monomials
        "K*1e400/(T*s + 1)",
        "K*" + "9" * 400 + "/(T*s + 1)",
    ]


def _toml(text: str) -> str:
    return f"transfer_function = {json.dumps(text)}\n[parameters]\n" + "\n".join(
        f"{n} = {{ range = [0.1, 10] }}" for n in ("K", "T", "os", "system", "a", "b", "c", "d", "e", "f")
    ) + "\ntau = { value = 0.05 }\n"


def _refused(capsys, tmp_path: Path, *argv: str, expect: str = "") -> str:
    before = set(Path(tmp_path).rglob("*"))
    code, out, err = run_cli(capsys, *argv)
    assert code != 0, out
    assert err.startswith("error:") and err.strip().count("\n") == 0, err
    assert "Traceback" not in err + out and "internal error" not in err
    assert expect in err, err
    assert set(Path(tmp_path).rglob("*")) == before  # nothing created (nor removed)
    return err


@pytest.mark.parametrize("index", range(len(_payloads(Path(MARKER)))))
def test_a_payload_in_a_model_file_is_refused_naming_the_token(tmp_path, capsys, monkeypatch, index):
    monkeypatch.chdir(tmp_path)
    marker = tmp_path / MARKER
    text = _payloads(marker)[index]
    spec = tmp_path / "m.toml"
    spec.write_text(_toml(text))
    err = _refused(capsys, tmp_path, "predict", "--beta", "-0.4", "--model-file", str(spec))
    assert "--model-file" in err and ("column" in err or "unknown symbol" in err), err
    assert not marker.exists()


@pytest.mark.parametrize("index", range(len(_limit_texts())))
def test_a_model_beyond_the_limits_is_refused_before_any_algebra(tmp_path, capsys, index):
    spec = tmp_path / "m.toml"
    spec.write_text(_toml(_limit_texts()[index]))
    _refused(capsys, tmp_path, "predict", "--beta", "-0.4", "--model-file", str(spec), expect="--model-file")


def test_numerator_denominator_lists_are_parsed_the_same_way(tmp_path, capsys):
    spec = tmp_path / "m.json"
    params = {"K": {"value": 2.0}, "T": {"value": 0.5}}
    for key, value, expect in [
        ("denominator", ["T"] * 201 + [1], "order 201"),
        ("denominator", ["T.func", 1], "attribute '.func'"),
        ("denominator", [{"a": 1}, 1], "denominator[0]"),
        ("numerator", ["__import__('os')"], "__import__"),
    ]:
        body = {"numerator": ["K"], "denominator": ["T", 1], "parameters": params, key: value}
        spec.write_text(json.dumps(body))
        _refused(capsys, tmp_path, "predict", "--beta", "-0.4", "--model-file", str(spec), expect=expect)


@pytest.mark.parametrize("item, expect", [
    ("T=1e-300", "physical range"), ("T=1e300", "physical range"), ("T=nan", "finite"), ("T=inf", "finite"),
])
def test_a_parameter_outside_the_physical_range_is_refused(tmp_path, capsys, item, expect):
    _refused(capsys, tmp_path, "predict", "--beta", "-0.4", "--model", "fopdt", "--param", "K=1", "--param", item,
             "--param", "tau=0.1", expect=expect)
    spec = tmp_path / "m.toml"
    spec.write_text('transfer_function = "K/(T*s + 1)"\n[parameters]\nK = { value = 1 }\nT = { value = 1e-300 }\n')
    _refused(capsys, tmp_path, "predict", "--beta", "-0.4", "--model-file", str(spec), expect="physical range")


def _deep_json(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth


@pytest.mark.parametrize("argv", [
    ("predict", "--beta", "-0.4", "--model-file", "{deep}"),
    ("tune", "{deep}", "--tp", "0.0422"),
    ("plan", "--from", "{deep}", "--tp", "0.0422", "--max-amplitude", "0.5", "--max-h", "0.2", "--time", "60"),
    ("compare", "{deep}", "{deep}"),
    ("vehicle", "{log}", "--tp", "0.0422", "--inner-gains", "{deep}"),
    ("simulate", "--cascade", "y", "--inner-tp", "0.0422", "--inner-td", "1.3", "--inner-tau", "0.03", "--inner-k", "30",
     "--inner-test", "-0.4", "--td", "2", "--tau", "0.03", "--test", "-0.4", "--inner-gains", "{deep}", "--out", "{out}"),
])
def test_json_nested_100000_deep_is_a_one_line_error(tmp_path, capsys, argv):
    deep = tmp_path / "deep.json"
    deep.write_text(_deep_json())
    good = tmp_path / "good.toml"
    good.write_text('transfer_function = "K*exp(-tau*s)/(T*s + 1)"\n[parameters]\nK = { range = [0.1, 10] }\n'
                    'T = { range = [0.01, 10] }\ntau = { value = 0.05 }\n')
    log = Path(__file__).parent.parent / "sample_logs" / "design1_altitude.csv"
    names = {"deep": str(deep), "good": str(good), "log": str(log), "out": str(tmp_path / "out.csv")}
    err = _refused(capsys, tmp_path, *(a.format(**names) for a in argv))
    assert "nested" in err and "100000" in err, err


def test_billion_laughs_batch_config_is_refused(tmp_path, capsys):
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, name in zip("abcdefgh", "bcdefghi"):
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    config = tmp_path / "laughs.yaml"
    config.write_text("\n".join(lines) + "\n")
    assert config.stat().st_size < 400  # 9**9 values once expanded
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "a.csv").write_text("t,u,y\n0,0,0\n")
    (tmp_path / "out").mkdir()  # batch makes its --out folder before it reads the config
    _refused(capsys, tmp_path, "batch", str(logs), "--config", str(config), "--out", str(tmp_path / "out"),
             "--tp", "0.0422", expect="aliases expand")
    config.write_text("a: &a [*a]\n")
    _refused(capsys, tmp_path, "batch", str(logs), "--config", str(config), "--out", str(tmp_path / "out"),
             "--tp", "0.0422", expect="recursive")
    config.write_text("defaults: !!python/object/apply:os.system ['touch " + str(tmp_path / MARKER) + "']\n")
    _refused(capsys, tmp_path, "batch", str(logs), "--config", str(config), "--out", str(tmp_path / "out"),
             "--tp", "0.0422", expect="not valid YAML")
    config.write_text("[" * 100_000)
    _refused(capsys, tmp_path, "batch", str(logs), "--config", str(config), "--out", str(tmp_path / "out"),
             "--tp", "0.0422", expect="nested")


def _closed_form(w, K, den_factors, num=(1.0,), tau=0.0):
    den = np.array([1.0])
    for f in den_factors:
        den = np.polymul(den, f)
    return K * np.polyval(num, 1j * w) / np.polyval(den, 1j * w) * np.exp(-1j * w * tau), den


@pytest.mark.parametrize("text, values, num, factors", [
    ("K*exp(-tau*s)/(T*s + 1)**2", {"K": 2.0, "T": 0.5, "tau": 0.1}, (1.0,), [(0.5, 1.0), (0.5, 1.0)]),
    ("K*exp(-tau*s)/(T*s + 1)^2", {"K": 2.0, "T": 0.5, "tau": 0.1}, (1.0,), [(0.5, 1.0), (0.5, 1.0)]),
    ("K*(a*s + 1)*exp(-tau*s)/(s*(T1*s + 1)*(T2**2*s**2 + 2*z*T2*s + 1))",
     {"K": 1.3, "a": 0.05, "T1": 0.7, "T2": 0.2, "z": 0.3, "tau": 0.05}, (0.05, 1.0),
     [(1.0, 0.0), (0.7, 1.0), (0.04, 0.12, 1.0)]),
    ("-K/(-(T*s) - 1)", {"K": 3.0, "T": 2.0}, (1.0,), [(2.0, 1.0)]),
    ("K/(T*s + 1)**20", {"K": 1.0, "T": 0.1}, (1.0,), [(0.1, 1.0)] * 20),
    ("1/(s*(T*s + 1))", {"T": 0.25}, (1.0,), [(1.0, 0.0), (0.25, 1.0)]),
])
def test_legitimate_models_keep_their_coefficients(text, values, num, factors):
    model = declared_model(text, values)
    w = np.array([0.1, 1.0, 7.0, 40.0])
    G, den = _closed_form(w, values.get("K", 1.0), factors, num, values.get("tau", 0.0))
    assert model.frequency_response(w) == pytest.approx(G, rel=1e-12)
    assert model.realisation().order == len(den) - 1
    n, d = model._coefficients()
    # the same polynomials up to a common scale (the denominator's leading coefficient)
    assert d / d[0] == pytest.approx(den / den[0], rel=1e-12)
    assert n / d[0] == pytest.approx(np.asarray(num) / den[0], rel=1e-12)


def test_list_form_and_json_read_back_give_the_same_model(tmp_path):
    listed = parse_model_spec({"numerator": ["K"], "denominator": ["T**2", "2*T", 1], "delay": "tau",
                               "parameters": {"K": {"value": 2.0}, "T": {"value": 0.5}, "tau": {"value": 0.1}}})
    w = np.array([0.3, 3.0])
    G, _ = _closed_form(w, 2.0, [(0.5, 1.0), (0.5, 1.0)], tau=0.1)
    assert listed.frequency_response(w) == pytest.approx(G, rel=1e-12)
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"transfer_function": "K*exp(-tau*s)/(T*s + 1)**2",
                                "parameters": {"K": {"value": 2.0}, "T": {"value": 0.5}, "tau": {"value": 0.1}}}))
    assert load_model_file(path).frequency_response(w) == pytest.approx(G, rel=1e-12)


def test_a_result_json_of_a_declared_model_is_parsed_again_on_reading(tmp_path):
    from mrftcli.mrft.model import model_from_json

    data = declared_model("K*exp(-tau*s)/(T*s + 1)", {"K": 2.0, "T": 0.5, "tau": 0.1}).to_json()
    for hostile in _payloads(tmp_path / MARKER) + _limit_texts()[:3]:
        with pytest.raises(InputError):
            model_from_json({**data, "transfer_function": hostile})
    assert not (tmp_path / MARKER).exists()


@pytest.fixture(scope="module")
def declared_batch(tmp_path_factory):
    """A simulated double-lag relay recording, its declared model file, and a batch run over it."""
    from process_sim import Window, simulate, write_csv

    root = tmp_path_factory.mktemp("declared_batch")
    logs = root / "logs"
    logs.mkdir()
    windows = [Window("hysteresis", 1.0, -1.0, eps=e, duration=12.0, rest=2.0) for e in (0.02, 0.12)]
    t, u, y = simulate("sopdt", {"K": 1.5, "T1": 0.4, "T2": 0.4, "tau": 0.1}, windows, 50.0, 0.002, seed=3)
    write_csv(str(logs / "rec.csv"), t, u, y)
    spec = root / "double.toml"
    spec.write_text('transfer_function = "K*exp(-tau*s)/(T*s + 1)**2"\n[parameters]\nK = { range = [0.1, 10] }\n'
                    'T = { range = [0.01, 10] }\ntau = { range = [0.0, 1.0] }\n')
    from mrftcli.cli.main import main

    argv = ["batch", str(logs), "--model-file", str(spec), "--command-topic", "u_relay", "--output-topic",
            "y_output", "--out", str(root / "out")]
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code in (0, None)
    return root, argv


def test_a_hostile_model_read_back_from_results_and_batch_records_is_refused(declared_batch, capsys):
    root, argv = declared_batch
    record_path = next((root / "out" / "logs").glob("*.json"))
    legit = "K*exp(-tau*s)/(T*s + 1)**2"
    marker = root / MARKER
    hostile = _payloads(marker)[0]
    record = json.loads(record_path.read_text())
    # an analysis JSON of the declared model, its text replaced: tune and plan --from read the model back
    result = record["loops"][0]["result"]
    assert result["identification"]["model"]["transfer_function"] == legit
    result["identification"]["model"]["transfer_function"] = hostile
    bad = root / "bad.json"
    bad.write_text(json.dumps(result))
    _refused(capsys, root / "out", "tune", str(bad), expect="not allowed")
    _refused(capsys, root / "out", "plan", "--model-file", str(root / "double.toml"), "--from", str(bad),
             expect="not allowed")
    # the batch's own record, edited: not taken as up to date, analysed again (the record rewritten)
    record_path.write_text(json.dumps(record))
    code, out, err = run_cli(capsys, *argv)
    assert code == 0 and "skipped-uptodate" not in out, out + err
    again = json.loads(next((root / "out" / "logs").glob("*.json")).read_text())
    assert again["loops"][0]["result"]["identification"]["model"]["transfer_function"] == legit
    assert not marker.exists()
    code, out, _ = run_cli(capsys, *argv)  # and a legitimate record is kept
    assert code == 0 and "skipped-uptodate" in out


def _json_mcap(path: Path, schema: str, message: bytes) -> None:
    """An MCAP of two JSON-encoded topics (a relay command and an output), one with the given schema and
    message text (written with the ``mcap`` library, not mrftcli's writer)."""
    from mcap.writer import Writer

    plain = json.dumps({"type": "object", "properties": {"data": {"type": "number"}}})
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        ids = {}
        for topic, text in (("/cmd", plain), ("/out", schema)):
            sid = writer.register_schema(name=topic.strip("/"), encoding="jsonschema", data=text.encode())
            ids[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        for i in range(50):
            t = i * 10_000_000
            writer.add_message(ids["/cmd"], log_time=t, data=json.dumps({"data": float(i % 2)}).encode(), publish_time=t)
            writer.add_message(ids["/out"], log_time=t, data=message if i == 25 else b'{"data": 0.5}',
                               publish_time=t)
        writer.finish()


@pytest.mark.parametrize("deep", ["schema", "message"])
def test_json_nested_100000_deep_in_an_mcap_is_a_one_line_error(tmp_path, capsys, deep):
    plain = json.dumps({"type": "object", "properties": {"data": {"type": "number"}}})
    log = tmp_path / "deep.mcap"
    _json_mcap(log, _deep_json() if deep == "schema" else plain,
               _deep_json().encode() if deep == "message" else b'{"data": 0.5}')
    for argv in (("topics", str(log), "--fields"), ("analyze", str(log), "--tp", "0.0422", "--command-topic", "/cmd:data",
                                        "--output-topic", "/out:data")):
        code, out, err = run_cli(capsys, *argv)
        assert "Traceback" not in err and "internal error" not in err, err
        assert code == 0 or (err.startswith("error:") and err.strip().count("\n") == 0), err


def test_a_manifold_whose_metadata_is_nested_100000_deep_is_refused(tmp_path):
    from mrftcli.mrft.ufm import load_manifold

    path = tmp_path / "m.npz"
    grid = np.zeros(3)
    np.savez(path, metadata=np.array(_deep_json()), tp=grid, td=grid, theta=grid, amplitude=grid)
    with pytest.raises(InputError, match="nested 100000 deep"):
        load_manifold(path)
    np.savez(path, metadata=np.array("[1, 2]"), tp=grid, td=grid, theta=grid, amplitude=grid)
    with pytest.raises(InputError, match="not a mrft-ident manifold"):
        load_manifold(path)
