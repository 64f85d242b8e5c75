"""mrft-ident: identify multirotor loop models from MRFT flight logs.

The pipeline mirrors the modules: :mod:`mrftcli.io` -> :mod:`mrftcli.segment.core` ->
:mod:`mrftcli.mrft.identify` (with :mod:`mrftcli.mrft.lprs` and :mod:`mrftcli.mrft.ufm`) -> :mod:`mrftcli.diagnose.selection`
-> :mod:`mrftcli.report`; :mod:`mrftcli.cli.main` is a thin click layer on top.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mrft-ident")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
