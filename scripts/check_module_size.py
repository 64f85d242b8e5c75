"""Fail when a module of the package is longer than 900 lines (the architecture's limit; CI runs this)."""

from __future__ import annotations

import sys
from pathlib import Path

LIMIT = 900


def main() -> int:
    root = Path(__file__).resolve().parent.parent / "mrftcli"
    long = [(p, n) for p in sorted(root.rglob("*.py")) if (n := len(p.read_text().splitlines())) > LIMIT]
    for path, n in long:
        print(f"{path.relative_to(root.parent)}: {n} lines (limit {LIMIT}): split it by job")
    return 1 if long else 0


if __name__ == "__main__":
    sys.exit(main())
