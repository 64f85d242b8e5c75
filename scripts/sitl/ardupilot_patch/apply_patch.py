"""Add mrft-ident's main-loop MRFT relay to an ArduPilot tree (issue 41; idempotent).

usage: python apply_patch.py ARDUPILOT_TREE

Copies ``MRFT_relay.h``, ``MRFT_task.h`` and ``MRFT_task.cpp`` into ``ArduCopter/`` and adds two lines to
``ArduCopter/Copter.cpp``: the header, and the task in the scheduler table right after
``FAST_TASK(update_flight_mode)``. No other file of ArduPilot changes (Copter.h is untouched, so an
incremental build recompiles two files).
"""
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
FILES = ("MRFT_relay.h", "MRFT_task.h", "MRFT_task.cpp")
INCLUDE = '#include "MRFT_task.h"  // mrft-ident: the main-loop MRFT relay\n'
TASK = "    FAST_TASK_CLASS(MrftTask, &mrft_task, update),  // mrft-ident: the MRFT relay, after the flight mode\n"


def main(tree: Path) -> int:
    copter = tree / "ArduCopter"
    src = copter / "Copter.cpp"
    if not src.exists():
        print(f"error: {src} not found: not an ArduPilot tree", file=sys.stderr)
        return 2
    for name in FILES:
        if not (copter / name).exists() or (copter / name).read_bytes() != (HERE / name).read_bytes():
            shutil.copy(HERE / name, copter / name)
    text = src.read_text(encoding="utf-8")
    if INCLUDE not in text:
        anchor = '#include "Copter.h"\n'
        if anchor not in text:
            print(f"error: {anchor.strip()} not found in {src}", file=sys.stderr)
            return 2
        text = text.replace(anchor, anchor + INCLUDE, 1)
    if TASK not in text:
        anchor = "    FAST_TASK(update_flight_mode),\n"
        if anchor not in text:
            print(f"error: FAST_TASK(update_flight_mode) not found in {src}: this ArduPilot is older than "
                  "4.5 (no FAST_TASK table); add the task to its fast loop by hand", file=sys.stderr)
            return 2
        text = text.replace(anchor, anchor + TASK, 1)
    if src.read_text(encoding="utf-8") != text:
        src.write_text(text, encoding="utf-8")
        print(f"patched {src}")
    else:
        print(f"already patched: {src}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    raise SystemExit(main(Path(sys.argv[1])))
