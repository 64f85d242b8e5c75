"""Issue 37's acceptance check on ArduCopter SITL: a ``tune --export ardupilot`` altitude file is loaded into
the stack's own SITL, read back, armed (ArduPilot's pre-arm checks, not ours) and flown.

Steps: write the export of ``sample_logs/design1_altitude.mcap`` (``--stack-version 4.6``: the SITL tree,
``blitzy-public-samples/ardupilot-blitzy`` master of 2025-07-21, predates 4.7's rename and has 4.6's names;
``--stack-version 4.7`` names are reported as missing there); start SITL with the harness of issue 41
(``scripts/sitl/sitl.py``); as a control, set ``PSC_ACCZ_I`` 0 (the value the old export wrote) and try to
arm: ArduPilot must refuse with "PSC_ACCZ_I must be > 0"; then load every value of the file, read each
back, arm, take off in GUIDED to 5 m, hold 20 s (the altitude's spread printed), land.

Run: ``python benchmarks/sitl_export_arms.py --ap /work/sitl/ardupilot`` (a few minutes; needs
``build/sitl/bin/arducopter``). Prints one line per step and PASS/FAIL.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "sitl"))


def _export(version: str, out: Path) -> None:
    cmd = [sys.executable, "-m", "mrftcli.cli", "tune", str(ROOT / "sample_logs/design1_altitude.mcap"), "--tp",
           "0.0422", "--loop", "altitude", "--export", "ardupilot", "--stack-version", version, "--hover-thrust",
           "0.5", "--out", str(out), "-q"]
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if run.returncode:
        raise SystemExit(f"tune failed: {run.stderr.strip()}")


def _instance(sitl_cls: type, instance: int) -> type:
    """The harness's Sitl on SITL instance ``instance`` (``-I N``, MAVLink on tcp 5760 + 10 N), so it runs beside
    another engineer's SITL on instance 0."""
    import subprocess as sp

    class Instance(sitl_cls):  # type: ignore[misc,valid-type]
        def start(self):  # type: ignore[no-untyped-def]
            real = sp.Popen

            def popen(cmd, *a, **k):  # type: ignore[no-untyped-def]
                return real([f"-I{instance}" if c == "-I0" else c for c in cmd], *a, **k)

            sp.Popen = popen  # the harness's start() builds "-I0"; only this call is redirected
            try:
                return super().start()
            finally:
                sp.Popen = real

    return Instance


def main() -> int:
    from sitl import Sitl as Sitl0, SitlError, load_params, read_param_file  # scripts/sitl (issue 41)

    Sitl = _instance(Sitl0, 3)

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ap", type=Path, default=Path("/work/sitl/ardupilot"), help="the built ArduPilot tree")
    ap.add_argument("--speedup", type=float, default=5.0)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="sitl37-"))
    f46, f47 = work / "alt46.param", work / "alt47.param"
    _export("4.6", f46)
    _export("4.7", f47)
    params = read_param_file(f46)
    print(f"export (4.6 names): {params}")
    ok = True
    with Sitl(args.ap, work / "run", speedup=args.speedup, port=5790) as sitl:
        sitl.wait(5)
        missing = []
        for name in read_param_file(f47):
            try:
                sitl.get_param(name, timeout=2.0)
            except SitlError:
                missing.append(name)
        print(f"4.7 names this firmware lacks (a ground station would skip them): {missing}")
        sitl.set_param("PSC_ACCZ_I", 0.0)
        try:
            refusals = sitl.arm(timeout_s=30)
            print(f"control: armed with PSC_ACCZ_I 0 (unexpected); refusals {refusals}")
            ok = False
            sitl.mav.arducopter_disarm()
            sitl.wait(3)
        except SitlError as err:
            seen = "PSC_ACCZ_I must be > 0" in str(err) or any("PSC_ACCZ_I" in t for t in sitl.texts)
            print(f"control: PSC_ACCZ_I 0 refused to arm: {seen} ({err})")
            ok &= seen
        rows = load_params(sitl, params)
        changed = [r for r in rows if not r["unchanged"]]
        print(f"loaded {len(rows)} values, read back unchanged: {len(rows) - len(changed)}; changed: {changed}")
        ok &= not changed
        sitl.set_mode("GUIDED")
        refusals = sitl.arm()
        print(f"armed with the export (pre-arm refusals while the EKF settled: {sorted(set(refusals))})")
        sitl.takeoff(5.0)
        alts = []
        for _ in range(40):  # 20 simulated seconds, every 0.5 s
            sitl.wait(0.5)
            alts.append(sitl.altitude())
        spread = max(alts) - min(alts)
        print(f"hold 5 m: altitude {min(alts):.2f}-{max(alts):.2f} m (spread {spread:.2f} m)")
        ok &= spread < 1.0
        sitl.land()
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
