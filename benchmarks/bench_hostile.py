"""Broken and hostile files and option sets through the CLI, under a memory cap (tracker issues 29, 35).

Builds the corpus (``scripts/make_hostile_corpus.py``) and runs ``analyze``, ``topics`` and
``diagnose`` on every case, each in its own process with an address-space cap
(``RLIMIT_AS``) and a timeout, then every option set of :data:`OPTION_CASES` (outputs onto someone's files
and links, absurd numbers, typed nonsense) in a folder of someone's files, and prints one table:

* internal errors: exit 1, another unexpected code, a signal, or ``Traceback`` on stderr;
* hangs: runs past the timeout;
* over 1 GB: peak resident memory (``ru_maxrss`` of the child) above 1 GB, or killed by the cap;
* warnings: a library warning (``SomethingWarning:``) on stderr;
* modified: the input's SHA-256 (a folder: of every file in it) differs after the run;
* wrong exit 0: ``analyze`` exited 0 on a file that must be refused, or with Td, tau or K outside
  the tolerance of the truth (:data:`TOLERANCE`).

Usage::

    nice -n 10 python benchmarks/bench_hostile.py [--big-rows 10000000] [--fast] [--only REGEX]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from make_hostile_corpus import build_corpus  # noqa: E402

#: the address-space cap of each run [bytes] (virtual: numpy's thread pools reserve more than they use)
MEMORY_CAP = 4 << 30
#: resident memory that counts as a failure [bytes]
RSS_LIMIT = 1 << 30
#: per-run timeout [s]
TIMEOUT_S = 120.0
#: relative error of Td, tau, K against the truth that still counts as right (the clean sample logs'
#: own errors reach 15 % on tau; a unit error is a factor of 1000)
TOLERANCE = {"Td": 0.35, "tau": 0.35, "K": 0.35}
COMMANDS = ("topics", "analyze", "diagnose")
#: the table's rows: the commands on every file, then the option sets (issue 35)
ROWS = (*COMMANDS, "options")
_WARNING = re.compile(r"\b[A-Z][A-Za-z]*Warning: ")


@dataclass(frozen=True)
class Run:
    """One command on one case."""

    case: str
    command: str
    code: int
    seconds: float
    rss_bytes: int
    stderr: str
    hang: bool
    modified: bool
    wrong: str  # why an exit 0 is wrong ('' when it is not)
    cpu_s: float = float("nan")  # user + system CPU [s] (the shared machine's load does not inflate it)

    @property
    def internal(self) -> bool:
        return (not self.hang and (self.code not in (0, 2, 3, 4, 5, 6, 7)
                                   or "Traceback" in self.stderr))

    @property
    def warned(self) -> bool:
        return bool(_WARNING.search(self.stderr))

    @property
    def big(self) -> bool:
        return self.rss_bytes > RSS_LIMIT or "MemoryError" in self.stderr


def digest(path: Path) -> str:
    """SHA-256 of a file, or of every file of a folder (names and bytes)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for p in files:
        h.update(str(p.relative_to(path.parent)).encode())
        with open(p, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _cap() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def _truth(entry: dict) -> dict | None:
    name = entry.get("truth")
    if not name:
        return None
    return json.loads((ROOT / "sample_logs" / f"{name}.truth.json").read_text())


def wrong_numbers(entry: dict, result: dict) -> str:
    """Why an analysis that exited 0 is wrong for this case ('' when it is right)."""
    truth = _truth(entry)
    if entry["expect"] == "refuse" or truth is None:
        return "exit 0 on a file that must be refused"
    bad = []
    for name, tol in TOLERANCE.items():
        got = (result.get("parameters") or {}).get(name, {}).get("value")
        if got is None or not abs(got / truth[name] - 1.0) <= tol:
            bad.append(f"{name} {got} (truth {truth[name]})")
    return ", ".join(bad)


def run_one(entry: dict, corpus: Path, command: str, timeout: float = TIMEOUT_S) -> Run:
    """Run ``mrft-ident COMMAND`` on one case in a capped subprocess."""
    path = corpus / entry["name"]
    before = digest(path)
    truth = _truth(entry)
    tp = str(truth["Tp"]) if truth else "0.05"
    with tempfile.TemporaryDirectory() as tmp:
        out_json = Path(tmp) / "result.json"
        argv = [sys.executable, "-m", "mrftcli", command, str(path)]
        if command != "topics":
            argv += ["--tp", tp, "--loop", entry.get("loop", "altitude"), *entry["args"]]
        if command == "analyze":
            argv += ["--json", str(out_json)]
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
        start = time.perf_counter()
        code, err, rss, hang, cpu = _capped(argv, env, tmp, timeout)
        seconds = time.perf_counter() - start
        wrong = ""
        if code == 0 and command == "analyze":
            result = json.loads(out_json.read_text()) if out_json.exists() else {}
            wrong = wrong_numbers(entry, result)
    return Run(entry["name"], command, code, seconds, rss, err, hang,
               digest(path) != before, wrong, cpu)


def _capped(argv: list[str], env: dict[str, str], cwd: str, timeout: float) -> tuple[int, str, int, bool, float]:
    """Exit code, stderr, peak RSS [bytes], whether it was killed at ``timeout`` [s], and its CPU time [s]."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            preexec_fn=_cap, cwd=cwd)
    killed = threading.Event()

    def kill() -> None:
        killed.set()
        proc.kill()

    timer = threading.Timer(timeout, kill)
    timer.start()
    assert proc.stderr is not None
    err = proc.stderr.read().decode(errors="replace")
    _pid, status, usage = os.wait4(proc.pid, 0)  # the child's own peak RSS (Linux: KiB)
    timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stderr.close()
    return proc.returncode, err, usage.ru_maxrss * 1024, killed.is_set(), usage.ru_utime + usage.ru_stime


# -- option sets (issue 35): outputs onto what the tool did not write, absurd numbers, typed nonsense --------
_LOG = str(ROOT / "sample_logs" / "design1_altitude.mcap")
_MODEL = ("--tp", "0.0422", "--td", "0.5", "--tau", "0.03")
_PLAN = ("plan", "--tp", "0.0422", "--from", _LOG, "--max-amplitude", "0.05", "--max-h", "0.2")
#: (name, argv, expect): ``refuse`` (exit 2-7, nothing in the folder changed), ``warn:WORD`` (exit 0 with
#: WORD on stderr). Each runs in a folder holding ``notes/`` (someone's files) and links into it.
OPTION_CASES: tuple[tuple[str, tuple[str, ...], str], ...] = (
    ("simulate_ros2_onto_folder", ("simulate", *_MODEL, "--test", "-0.4:0.2:2", "--format", "ros2-mcap",
                                   "--out", "notes"), "refuse"),
    ("simulate_out_link", ("simulate", *_MODEL, "--test", "-0.4:0.2:2", "--out", "link.mcap"), "refuse"),
    ("simulate_out_recorded_log", ("simulate", *_MODEL, "--test", "-0.4:0.2:2", "--out", "notes/flight.mcap"),
     "refuse"),
    ("predict_json_link", ("predict", *_MODEL, "--beta", "-0.4", "--json", "link.json"), "refuse"),
    ("predict_json_not_json", ("predict", *_MODEL, "--beta", "-0.4", "--json", "notes/a.txt"), "refuse"),
    ("analyze_mcap_out_link", ("analyze", _LOG, "--tp", "0.0422", "--mcap-out", "link.mcap"), "refuse"),
    ("analyze_report_link", ("analyze", _LOG, "--tp", "0.0422", "--report", "linkdir"), "refuse"),
    ("simulate_test_1e6s", ("simulate", *_MODEL, "--test", "-0.4:0.2:1e6", "--out", "x.mcap"), "refuse"),
    ("simulate_test_5e5s", ("simulate", *_MODEL, "--test", "-0.4:0.2:5e5", "--out", "x.mcap"), "refuse"),
    ("simulate_rate_1e7", ("simulate", *_MODEL, "--test", "-0.4", "--controller-rate", "1e7", "--out", "x.mcap"),
     "refuse"),
    ("predict_rate_1e300", ("predict", *_MODEL, "--beta", "-0.4", "--controller-rate", "1e300"), "refuse"),
    ("predict_td_1e300", ("predict", "--tp", "0.0422", "--td", "1e300", "--tau", "0.03", "--beta", "-0.4"), "refuse"),
    ("predict_tau_1e300", ("predict", "--tp", "0.0422", "--td", "0.5", "--tau", "1e300", "--beta", "-0.4"), "refuse"),
    ("tune_td_std_1e300", ("tune", *_MODEL, "--k", "1", "--td-std", "1e300", "--loop", "altitude",
                           "--controller-rate", "200"), "refuse"),
    ("plan_time_1e300", (*_PLAN, "--time", "1e300"), "refuse"),
    ("plan_tests4_time_1e9", (*_PLAN, "--tests", "4", "--time", "1e9"), "refuse"),
    ("analyze_eps_1e300", ("analyze", _LOG, "--model", "fopdt", "--relay", "hysteresis", "--eps", "1e300"), "refuse"),
    ("identify_amplitude_typo", ("identify", "--tp", "0.1", "--test", "-0.4:0.705643:0.078530:1", "--test",
                                 "-0.7:1.018843:0.0035602:1"), "warn:disagree"),
)


def _option_folder(folder: Path) -> None:
    """Someone's files, and links pointing into them, where each option set runs."""
    notes = folder / "notes"
    notes.mkdir()
    (notes / "a.txt").write_text("field notes: the only copy\n")
    (notes / "flight.mcap").write_bytes((ROOT / "sample_logs" / "design1_altitude.mcap").read_bytes())
    for name, target in (("link.mcap", notes / "a.txt"), ("link.json", notes / "a.txt"), ("linkdir", notes)):
        (folder / name).symlink_to(target)


def run_options(name: str, args: tuple[str, ...], expect: str, timeout: float = TIMEOUT_S) -> Run:
    """One option set in a capped subprocess, in a folder of someone's files (:func:`_option_folder`)."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        _option_folder(folder)
        before = digest(folder)
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
        start = time.perf_counter()
        code, err, rss, hang, cpu = _capped([sys.executable, "-m", "mrftcli", *args], env, tmp, timeout)
        seconds = time.perf_counter() - start
        changed = digest(folder) != before or sorted(p.name for p in folder.iterdir()) != [
            "link.json", "link.mcap", "linkdir", "notes"]
    wrong = ""
    if expect == "refuse" and code == 0:
        wrong = "exit 0 on options that must be refused"
    elif expect.startswith("warn:") and (code != 0 or expect[5:] not in err):
        wrong = f"no warning '{expect[5:]}' (exit {code})"
    return Run(name, "options", code, seconds, rss, err, hang, changed, wrong, cpu)


def table(runs: list[Run]) -> str:
    """The summary table (per command) and one line per failing run."""
    lines = ["| command | runs | internal errors | hangs | > 1 GB | warnings | inputs modified | wrong exit 0 |",
             "|---|---|---|---|---|---|---|---|"]
    for command in ROWS:
        rs = [r for r in runs if r.command == command]
        if not rs:
            continue
        lines.append(f"| {command} | {len(rs)} | {sum(r.internal for r in rs)} | {sum(r.hang for r in rs)} | "
                     f"{sum(r.big for r in rs)} | {sum(r.warned for r in rs)} | {sum(r.modified for r in rs)} | "
                     f"{sum(bool(r.wrong) for r in rs)} |")
    bad = [r for r in runs if r.internal or r.hang or r.big or r.warned or r.modified or r.wrong]
    if bad:
        lines.append("")
        lines.append("failures:")
    for r in bad:
        what = [w for w, flag in (("internal", r.internal), ("hang", r.hang), ("big", r.big),
                                  ("warning", r.warned), ("modified", r.modified)) if flag]
        if r.wrong:
            what.append(f"wrong: {r.wrong}")
        last = r.stderr.strip().splitlines()[-1:] or [""]
        lines.append(f"  {r.case} {r.command}: exit {r.code}, {', '.join(what)}: {last[0][:160]}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big-rows", type=int, default=1_000_000, help="rows of the big CSV (issue: 10000000)")
    parser.add_argument("--fast", action="store_true", help="only the cases tests/test_hostile.py runs")
    parser.add_argument("--only", help="cases whose name matches this regex")
    parser.add_argument("--commands", default=",".join(COMMANDS))
    parser.add_argument("--corpus", type=Path, help="build into this folder (default: a temporary one)")
    parser.add_argument("--verbose", action="store_true", help="print each run as it ends")
    parser.add_argument("--no-options", action="store_true", help="skip the option sets (issue 35)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        corpus = args.corpus or Path(tmp) / "corpus"
        manifest = build_corpus(corpus, big_rows=args.big_rows, only=args.only)
        if args.fast:
            manifest = [e for e in manifest if e["fast"]]
        runs = []
        for entry in manifest:
            for command in args.commands.split(","):
                run = run_one(entry, corpus, command)
                runs.append(run)
                if args.verbose:
                    print(f"{run.case:36s} {command:9s} exit {run.code} {run.seconds:6.1f} s "
                          f"({run.cpu_s:6.1f} s CPU) {run.rss_bytes / 1e6:7.0f} MB {run.wrong}", flush=True)
        if not args.no_options:
            for name, option_args, expect in OPTION_CASES:
                if args.only and not re.search(args.only, name):
                    continue
                run = run_options(name, option_args, expect)
                runs.append(run)
                if args.verbose:
                    print(f"{run.case:36s} options   exit {run.code} {run.seconds:6.1f} s ({run.cpu_s:6.1f} s CPU) "
                          f"{run.rss_bytes / 1e6:7.0f} MB {run.wrong}", flush=True)
        print(f"{len(manifest)} cases x {args.commands}, {sum(r.command == 'options' for r in runs)} option sets: memory cap {MEMORY_CAP >> 30} GiB (address space), "
              f"timeout {TIMEOUT_S:.0f} s")
        print(table(runs))
        slow = max(runs, key=lambda r: r.seconds)
        print(f"longest run: {slow.case} {slow.command} {slow.seconds:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
