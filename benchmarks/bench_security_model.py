"""Hostile model texts, JSON and YAML through the CLI: time and peak memory of each refusal (issue 35, part A).

Each case is a file built here (the payloads of ``tests/test_security_model_text.py`` and the issue's
sizes), given to the CLI in its own process under an address-space cap (``RLIMIT_AS``) and a timeout.
Printed per case: exit code, wall time [s], peak resident memory [MiB] (``ru_maxrss`` of the child),
whether stderr is one line without a traceback, whether the marker file a payload would create exists;
and, as the baseline measured in the same run, the same command on the legitimate model file (its
figures are those of any CLI start: imports). The issue's "before" figures (3.8 GB, timeouts,
internal errors) are its own, from the sympy ``parse_expr`` reader this replaces.

Usage::

    nice -n 10 python benchmarks/bench_security_model.py [--only REGEX]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_security_model_text import _deep_json, _limit_texts, _payloads, _toml  # noqa: E402

#: the address-space cap of each run [bytes] (virtual: numpy's thread pools reserve more than they use)
MEMORY_CAP = 4 << 30
TIMEOUT_S = 60.0
PREDICT = ("predict", "--beta", "-0.4")
#: the legitimate model file of the baseline (every parameter known: predict draws its limit cycle)
GOOD = ('transfer_function = "K*exp(-tau*s)/(T*s + 1)**2"\n[parameters]\nK = { value = 2.0 }\n'
        'T = { value = 0.5 }\ntau = { value = 0.1 }\n')


def _laughs() -> str:
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, name in zip("abcdefgh", "bcdefghi"):
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def _cases(tmp: Path) -> list[tuple[str, list[str]]]:
    marker = tmp / "MARKER"
    cases: list[tuple[str, list[str]]] = []
    good = tmp / "good.toml"
    good.write_text(GOOD)
    cases.append(("baseline: legitimate model", [*PREDICT, "--model-file", str(good)]))
    for i, text in enumerate(_payloads(marker) + _limit_texts()):
        path = tmp / f"m{i}.toml"
        path.write_text(_toml(text))
        cases.append((f"model: {text[:48]!r}", [*PREDICT, "--model-file", str(path)]))
    deep = tmp / "deep.json"
    deep.write_text(_deep_json())
    log = ROOT / "sample_logs" / "design1_altitude.csv"
    cases += [
        ("JSON 100,000 deep: --model-file", [*PREDICT, "--model-file", str(deep)]),
        ("JSON 100,000 deep: tune", ["tune", str(deep), "--tp", "0.0422"]),
        ("JSON 100,000 deep: plan --from", ["plan", "--from", str(deep), "--tp", "0.0422", "--max-amplitude", "0.5",
                                             "--max-h", "0.2", "--time", "60"]),
        ("JSON 100,000 deep: compare", ["compare", str(deep), str(deep)]),
        ("JSON 100,000 deep: vehicle --inner-gains", ["vehicle", str(log), "--tp", "0.0422", "--inner-gains", str(deep)]),
        ("--param T=1e-300", [*PREDICT, "--model", "fopdt", "--param", "K=1", "--param", "T=1e-300",
                              "--param", "tau=0.1"]),
    ]
    laughs = tmp / "laughs.yaml"
    laughs.write_text(_laughs())
    logs = tmp / "logs"
    logs.mkdir()
    (logs / "a.csv").write_text("t,u,y\n0,0,0\n")
    cases.append((f"billion laughs ({laughs.stat().st_size} B): batch --config",
                  ["batch", str(logs), "--config", str(laughs), "--out", str(tmp / "out"), "--tp", "0.0422"]))
    return cases


#: the CLI in the child, which writes its own peak resident memory [KiB] and CPU time [s] to the file
#: named by argv[1]
_CHILD = """
import resource, sys
from mrftcli.cli.main import main
code = 0
try:
    main(sys.argv[2:])
except SystemExit as done:
    code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
finally:
    use = resource.getrusage(resource.RUSAGE_SELF)
    open(sys.argv[1], "w").write(f"{use.ru_maxrss} {use.ru_utime + use.ru_stime}")
sys.exit(code)
"""


def _run(argv: list[str], cwd: Path) -> tuple[int, float, float, float, str]:
    """(exit code, wall time [s], CPU time [s], peak resident memory [MiB], stderr) of ``mrft-ident ARGV``."""
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))

    peak_file = cwd / "peak.txt"
    peak_file.unlink(missing_ok=True)
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(peak_file), *argv], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=cap)
    try:
        _, err = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return -9, TIMEOUT_S, float("nan"), float("nan"), "timeout"
    wall = time.perf_counter() - start
    rss, cpu = (float(x) for x in peak_file.read_text().split()) if peak_file.exists() else (math.nan, math.nan)
    return proc.returncode, wall, cpu, rss / 1024.0, err


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="run only the cases whose label matches this regex")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        cases = _cases(tmp)
        for label, argv in cases:
            if args.only and not re.search(args.only, label) and not label.startswith("baseline"):
                continue
            code, wall, cpu, peak, err = _run(argv, tmp)
            one_line = err.strip().count("\n") == 0 and "Traceback" not in err and "internal error" not in err
            rows.append((label, code, wall, cpu, peak, one_line, (tmp / "MARKER").exists(), err.strip()[:110]))
    base = rows[0]
    print(f"{'case':60s} {'exit':>4s} {'wall s':>7s} {'CPU s':>6s} {'x base':>6s} {'peak MiB':>8s}  1-line  marker  "
          "message")
    for label, code, wall, cpu, peak, one_line, marker, msg in rows:
        print(f"{label:60.60s} {code:4d} {wall:7.2f} {cpu:6.2f} {cpu / base[3]:6.2f} {peak:8.0f}  {str(one_line):6s}  "
              f"{str(marker):6s}  {msg}")
    refused = rows[1:]
    bad = [r for r in refused if r[1] in (0, 1) or r[1] < 0 or not r[5] or r[6]]
    print(f"\nbaseline (the legitimate model, exit {base[1]}): {base[2]:.2f} s wall, {base[3]:.2f} s CPU, "
          f"{base[4]:.0f} MiB")
    print(f"{len(refused)} hostile cases: {len(refused) - len(bad)} refused in one line (exit 2); "
          f"max {max(r[2] for r in refused):.2f} s wall, {max(r[3] for r in refused):.2f} s CPU "
          f"({max(r[3] for r in refused) / base[3]:.2f}x the baseline), {max(r[4] for r in refused):.0f} MiB; "
          f"markers created: {sum(r[6] for r in refused)}")
    for r in bad:
        print("NOT REFUSED CLEANLY:", r[0], r[1], r[7])
    print(json.dumps({"cases": len(refused), "bad": len(bad)}))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
