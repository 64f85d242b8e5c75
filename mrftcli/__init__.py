"""mrft-ident: identify multirotor loop models from MRFT flight logs.

The pipeline mirrors the modules: :mod:`mrftcli.readers` -> :mod:`mrftcli.segment` ->
:mod:`mrftcli.identify` (with :mod:`mrftcli.lprs` and :mod:`mrftcli.ufm`) -> :mod:`mrftcli.diagnose`
-> :mod:`mrftcli.report`; :mod:`mrftcli.cli` is a thin click layer on top.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mrft-ident")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
