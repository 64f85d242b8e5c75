"""Shorten a PX4 ULog for the repository: PX4's own messages, fewer of them (issue 42's sample logs).

Keeps the header, every definition and every message that is not topic data (parameters and their
changes, logged text, subscriptions) byte for byte, and of the data messages (``D``) only those of the
topics not dropped whose timestamp falls inside ``[t0, t1]`` (seconds of the log's clock). What is kept
is what PX4 wrote; the sidecar says what was cut. ULog: https://docs.px4.io/main/en/dev_log/ulog_file_format.html

    python scripts/sitl/px4/trim_ulog.py IN.ulg OUT.ulg --from 50 --to 130 --drop vehicle_local_position_groundtruth
"""

from __future__ import annotations

import argparse
import struct
from pathlib import Path

__all__ = ["trim_ulog"]

_HEADER = 16  # magic (7), version (1), start timestamp (8)


def trim_ulog(src: Path, dst: Path, t0: float, t1: float, drop: frozenset[str] = frozenset()) -> dict[str, int]:
    """Write ``src`` to ``dst`` keeping the data messages of the topics not in ``drop`` stamped in
    ``[t0, t1]`` [s]; the counts of data messages kept and cut."""
    data = src.read_bytes()
    out = bytearray(data[:_HEADER])
    names: dict[int, str] = {}
    kept = cut = 0
    pos = _HEADER
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        end = pos + 3 + size
        if end > len(data):
            break  # a message cut by the end of the file: left out, as PX4's readers do
        if kind == ord("A"):  # add_logged_message: multi_id (1), msg_id (2), message_name
            msg_id = struct.unpack_from("<H", data, pos + 4)[0]
            names[msg_id] = data[pos + 6:end].decode("ascii", "replace")
        if kind == ord("D"):
            msg_id, stamp = struct.unpack_from("<HQ", data, pos + 3)
            if names.get(msg_id) in drop or not t0 <= stamp * 1e-6 <= t1:
                cut += 1
                pos = end
                continue
            kept += 1
        out += data[pos:end]
        pos = end
    dst.write_bytes(bytes(out))
    return {"data_messages_kept": kept, "data_messages_cut": cut}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--from", dest="t0", type=float, default=0.0, help="first time kept [s, log clock]")
    ap.add_argument("--to", dest="t1", type=float, default=float("inf"), help="last time kept [s, log clock]")
    ap.add_argument("--drop", nargs="*", default=[], help="topics whose data are left out")
    args = ap.parse_args(argv)
    print(trim_ulog(args.src, args.dst, args.t0, args.t1, frozenset(args.drop)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
