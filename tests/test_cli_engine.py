"""CLI of the engine: predict, identify, build-ufm. One test runs ``python -m mrftcli`` in a subprocess (the
real process's exit code and output); the others run the same main() in this process (cli_helpers.run_main),
which a subprocess would only add its imports' CPU to."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from cli_helpers import run_main as run


def test_predict_json_paper_example():
    p = subprocess.run([sys.executable, "-m", "mrftcli", "predict", "--tp", "0.1", "--td", str(1 / 1.42),
                        "--tau", "0.06", "--beta", "-0.4", "--json"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["frequency_hz"] == pytest.approx(0.70564, rel=5e-4)
    assert d["amplitude"] == pytest.approx(0.078530 / 1.42, rel=1e-3)  # K = 1 here: K Td = 1/1.42


@pytest.mark.parametrize("args", [
    ("--tp", "0.1", "--td", "0.7", "--tau", "0.06", "--beta", "-0.4", "--controller-rate", "200"),
    ("--model", "fopdt", "--param", "K=2", "--param", "T=0.5", "--param", "tau=0.1", "--beta", "0", "--eps", "0.1"),
])
def test_predict_json_is_a_versioned_record(args):
    # predict --json is Prediction's record: schema_version 1, read back by from_json and written again unchanged
    from mrftcli.errors import InputError
    from mrftcli.jsonable import to_jsonable
    from mrftcli.mrft.relays import PREDICTION_SCHEMA_VERSION, Prediction

    p = run("predict", *args, "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["schema_version"] == PREDICTION_SCHEMA_VERSION == 1
    back = Prediction.from_json(d)
    assert back.cycle.frequency_hz == d["frequency_hz"] and back.cycle.t.size == 0
    assert (back.describing_function is None) == ("describing_function" not in d)
    assert to_jsonable(back.to_json()) == d
    for bad in ({**d, "schema_version": 2}, {k: v for k, v in d.items() if k != "schema_version"},
                {**d, "period": "x"}, {k: v for k, v in d.items() if k != "relay"}):
        with pytest.raises(InputError, match="predict JSON"):
            Prediction.from_json(bad)


def test_predict_table_and_sampled():
    p = run("predict", "--tp", "0.1", "--td", "0.7", "--tau", "0.06", "--beta", "-0.7", "--controller-rate", "200")
    assert p.returncode == 0, p.stderr
    assert "frequency" in p.stdout and "sampled orbits" in p.stdout


def test_identify_json():
    p = run("identify", "--tp", "0.1", "--test", "-0.4:0.70564:0.078530:1", "--test", "-0.7:1.01884:0.035602:1", "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["parameters"]["Td"]["value"] == pytest.approx(1 / 1.42, rel=3e-3)
    assert d["parameters"]["tau"]["value"] == pytest.approx(0.06, rel=3e-3)
    assert d["parameters"]["K"]["value"] == pytest.approx(1.42, rel=3e-3)
    for k in ("Td", "tau", "K"):
        assert "std" in d["parameters"][k]


def test_identify_table():
    p = run("identify", "--tp", "0.1", "--test", "-0.4:0.70564", "--test", "-0.7:1.01884")
    assert p.returncode == 0, p.stderr
    assert "Td" in p.stdout and "tau" in p.stdout


def test_build_ufm(tmp_path):
    p = run("build-ufm", "--beta", "-0.4", "--beta", "-0.7", "--n-tp", "21", "--n-td", "21", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    names = sorted(x.name for x in tmp_path.iterdir())
    assert names == ["ufm_beta-0.400.json", "ufm_beta-0.400.npz", "ufm_beta-0.700.json", "ufm_beta-0.700.npz"]


@pytest.mark.parametrize(
    "args, code, text",
    [
        (("predict", "--tp", "0.1", "--td", "0.7", "--tau", "0.06", "--beta", "-1.2"), 2, "beta"),
        (("predict", "--tp", "0.1", "--td", "0.7", "--tau", "-0.06", "--beta", "-0.4"), 2, "tau"),
        (("predict", "--tp", "-0.1", "--td", "0.7", "--tau", "0.06", "--beta", "-0.4"), 2, "Tp"),
        (("predict", "--tp", "0.1", "--td", "0.7", "--tau", "0.06", "--beta", "-0.4", "--h", "0"), 2, "h"),
        (("identify", "--tp", "0.1", "--test", "-0.4:0.7"), 6, "two tests"),  # too few tests: exit 6 (issue 25)
        (("identify", "--tp", "0.1", "--test", "-0.4:0.7", "--test", "-0.7:0.5"), 5, "do not intersect"),
        (("identify", "--tp", "0.3", "--test", "0.3:40", "--test", "-0.7:50"), 5, "too fast"),
        (("identify", "--tp", "0.1", "--test", "1.4:0.7", "--test", "-0.7:1.0"), 2, "beta"),
        (("identify", "--tp", "0.1", "--test", "-0.4:x", "--test", "-0.7:1.0"), 2, "number"),
        (("identify", "--tp", "-0.1", "--test", "-0.4:0.7", "--test", "-0.7:1.0"), 2, "Tp"),
        (("build-ufm", "--beta", "-1.0", "--out", "x"), 2, "beta"),
    ],
)
def test_bad_input_one_line_error(args, code, text):
    p = run(*args)
    assert p.returncode == code, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.strip().splitlines() if ln.strip()]
    assert any(text in ln for ln in lines), p.stderr
    if code != 2 or lines[0].startswith("error:"):
        assert len(lines) == 1
