"""icefarm: procedural icicles and glaze ice on any mesh, rendered in batch."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("icefarm")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0"
