"""The command line: ``icefarm`` and its commands (`main`)."""

from .main import main

__all__ = ["main"]
