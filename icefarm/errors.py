"""The exception types the command line turns into a clean line and an exit status."""

from __future__ import annotations

import reprlib
import signal
from typing import Any


class InputError(ValueError):
    """Bad user input (a parameter, a mesh, a manifest): the message says what and how to fix it."""


class Interrupted(KeyboardInterrupt):
    """A sweep stopped by a signal (SIGTERM from ``timeout``, ``scancel``, ``docker stop``;
    SIGHUP; Ctrl-C's SIGINT): its workers were ended, its done jobs are kept.

    Attributes
    ----------
    signum : int
    summary : SweepSummary or None
        What became of the jobs until then (set by `icefarm.farm.sweep.run_sweep`).
    """

    def __init__(self, signum: int = signal.SIGINT, summary: Any = None):
        super().__init__(signum)
        self.signum = int(signum)
        self.summary = summary

    @property
    def name(self) -> str:
        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return f"signal {self.signum}"

    @property
    def exit_code(self) -> int:
        """128 + the signal number, as a shell reports a process ended by it (Ctrl-C: 130)."""
        return 128 + self.signum


def cannot_write(exc: OSError, what: str) -> InputError:
    """One line for ``exc``, met writing ``what`` (a full disk, a folder made read-only), in
    place of a traceback: ``cannot write WHAT: No space left on device (FILE)``."""
    return InputError(f"cannot write {what}: {exc.strerror or exc} ({exc.filename or what})")


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = _SHORT.maxset = 6
_SHORT.maxlevel = 3


def short_repr(value: Any) -> str:
    """``repr(value)`` cut to a few dozen characters, without ever building the whole repr
    (a YAML alias bomb expands to billions of items)."""
    return _SHORT.repr(value)


MAX_LINE = 400


def one_line_each(message: str, max_line: int = MAX_LINE, max_lines: int = 60) -> str:
    """``message`` with each line cut to ``max_line`` characters and at most ``max_lines``
    lines (the command line's safety net against a message quoting a huge value)."""
    lines = str(message).splitlines() or [""]
    out = [line if len(line) <= max_line else line[:max_line - 3] + "..." for line in lines[:max_lines]]
    if len(lines) > max_lines:
        out.append(f"... and {len(lines) - max_lines} more lines")
    return "\n".join(out)


class CacheWarning(UserWarning):
    """A stage-cache entry was damaged (or unreadable) and was recomputed instead of used."""
