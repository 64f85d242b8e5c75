"""The installed package's version (a leaf module, so any layer may import it)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mrft-ident")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
