"""openemt: open software stack for electromagnetic position-and-orientation trackers."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("openemt")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
