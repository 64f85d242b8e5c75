"""One click command per module; :mod:`mrftcli.cli.main` imports them lazily.

Commands only parse options, call one library function and print; no maths here.
"""

from .main import cli, main

__all__ = ["main", "cli"]
