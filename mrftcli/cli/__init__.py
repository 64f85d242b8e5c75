"""One click command per module; :mod:`mrftcli.cli.main` imports them lazily.

Commands only parse options, call one library function and print; no maths here.
"""

import os

# The maths is many small matrices, where OpenBLAS's thread pool costs more than it gains (diagnose on a
# sample log: 2.3 -> 2.0 s CPU on 2 cores; more on many-core machines, and worse under load). The command
# line therefore runs BLAS single-threaded; this must happen before numpy loads, and a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .main import cli, main  # noqa: E402 - after the thread settings above

__all__ = ["main", "cli"]
