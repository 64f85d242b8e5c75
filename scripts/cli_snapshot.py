"""Record the CLI's output on every shipped sample log, to check a refactor changes none of it.

Runs ``analyze`` (text and ``--json -``), ``diagnose`` (``--json -``), ``topics``, ``batch`` (one job,
summary as JSON), ``predict`` and ``identify`` and writes each command's stdout, stderr and exit code
into one file per command under ``--out``. Run it before and after a change and compare the two
folders with ``--compare``::

    python scripts/cli_snapshot.py --out /tmp/before
    # ... change the code ...
    python scripts/cli_snapshot.py --out /tmp/after --compare /tmp/before

Output that depends on the wall clock or on temporary paths (batch's output folder) is normalised.
``--no-diagnose`` skips the slow diagnosis runs (about 15 s of CPU per log); ``--only REGEX`` runs
and compares only the outputs whose name matches (``analyze_text``, ``diagnose_json``, ``topics``,
``batch``, ``predict``, ``identify``, or a log's name).
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"


def _logs() -> list[tuple[Path, dict]]:
    out = []
    for truth in sorted(SAMPLES.rglob("*.truth.json")):
        name = truth.name[: -len(".truth.json")]
        log = truth.parent / name
        if not log.exists():
            continue
        out.append((log, json.loads(truth.read_text())))
    return out


def _run(args: list[str]) -> str:
    proc = subprocess.run([sys.executable, "-m", "mrftcli.cli", *args], capture_output=True, text=True,
                          cwd=ROOT)
    return f"$ mrft-ident {' '.join(args)}\n--- exit {proc.returncode}\n--- stdout\n{proc.stdout}--- stderr\n{proc.stderr}"


def _normalise(text: str, tmp: str) -> str:
    text = text.replace(tmp, "<TMP>")
    return re.sub(r"\d+(\.\d+)?\s*(s|it)/(it|s)\b", "<RATE>", text)


#: what differs between two runs of the same code: the checkout's path, file times, wall-clock figures
_VOLATILE = [
    (re.compile(r"(/[\w.-]+)+/sample_logs/"), "<ROOT>/sample_logs/"),
    (re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?\+00:00"), "<TIME>"),
    (re.compile(r'("elapsed_s": )[0-9.e-]+'), r"\1<ELAPSED>"),
    (re.compile(r"(,<TIME>,)[0-9.e-]+(,logs/)"), r"\1<ELAPSED>\2"),
    (re.compile(r"\.[0-9a-f]{8}\.json"), ".<PATH-HASH>.json"),
]


def _stable(text: str) -> str:
    """``text`` without what changes from run to run of the same code (compared, not stored)."""
    for pattern, repl in _VOLATILE:
        text = pattern.sub(repl, text)
    return text


def snapshot(out: Path, *, diagnose: bool, only: str | None = None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    jobs: dict[str, list[str]] = {}
    for log, truth in _logs():
        rel = str(log.relative_to(ROOT))
        key = rel.replace("/", "__")
        common = [rel, "--tp", repr(truth["Tp"]), "--loop", truth["loop"]]
        jobs[f"analyze_text__{key}"] = ["analyze", *common]
        jobs[f"analyze_json__{key}"] = ["analyze", *common, "--json", "-"]
        jobs[f"topics__{key}"] = ["topics", rel]
        if diagnose:
            jobs[f"diagnose_json__{key}"] = ["diagnose", *common, "--json", "-"]
    jobs["predict"] = ["predict", "--tp", "0.1", "--td", "0.7042", "--tau", "0.06", "--beta", "-0.4"]
    jobs["predict_json_rate"] = ["predict", "--tp", "0.1", "--td", "0.7042", "--tau", "0.06", "--beta", "-0.4",
                                 "--rate", "200", "--json"]
    jobs["identify"] = ["identify", "--tp", "0.1", "--test", "-0.4:0.70564", "--test", "-0.7:1.01884"]
    jobs["identify_json_k"] = ["identify", "--tp", "0.1", "--test", "-0.4:0.7056:0.0785:1",
                               "--test", "-0.7:1.0188:0.0356:1", "--json"]
    for name, args in jobs.items():
        if only and not re.search(only, name):
            continue
        (out / f"{name}.txt").write_text(_run(args))
        print(name, flush=True)
    if only and not re.search(only, "batch"):
        return
    with tempfile.TemporaryDirectory() as tmp:
        args = ["batch", "sample_logs", "--tp", "0.0422", "--jobs", "1", "--out", tmp, "--no-report", "--json",
                "--quiet"]
        text = _normalise(_run(args), tmp)
        (out / "batch.txt").write_text(text)
        for csv in sorted(Path(tmp).glob("*.csv")):
            (out / f"batch_{csv.name}.txt").write_text(_normalise(csv.read_text(), tmp))
    print("batch", flush=True)


def compare(after: Path, before: Path, only: str | None = None) -> int:
    differing = 0
    names = sorted({p.name for p in before.glob("*.txt")} | {p.name for p in after.glob("*.txt")})
    if only:
        names = [n for n in names if re.search(only, n)]
    for name in names:
        a, b = after / name, before / name
        if not a.exists() or not b.exists():
            print(f"only in one snapshot: {name}")
            differing += 1
            continue
        ta, tb = _stable(a.read_text()), _stable(b.read_text())
        if ta != tb:
            differing += 1
            diff = difflib.unified_diff(tb.splitlines(), ta.splitlines(),
                                        f"before/{name}", f"after/{name}", lineterm="", n=1)
            print("\n".join(list(diff)[:40]))
    print(f"{len(names) - differing}/{len(names)} outputs identical")
    return 1 if differing else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="folder for this snapshot")
    parser.add_argument("--compare-only", action="store_true", help="compare --out with --compare, run nothing")
    parser.add_argument("--compare", type=Path, help="an earlier snapshot to compare against")
    parser.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis runs")
    parser.add_argument("--only", metavar="REGEX", help="run (and compare) only the outputs whose name matches")
    args = parser.parse_args()
    if not args.compare_only:
        snapshot(args.out, diagnose=not args.no_diagnose, only=args.only)
    return compare(args.out, args.compare, args.only) if args.compare else 0


if __name__ == "__main__":
    sys.exit(main())
