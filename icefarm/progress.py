"""What a job is doing, while it does it: a live line on a terminal, plain lines in a log.

`StepProgress` follows a job's steps (prepare, water, ..., surface, render, usd). On a
terminal it keeps one line that names the step, what it is doing inside it (the surface
stage says which of its parts it is on: glaze coat, icicle field, meshing, ripples) and the
seconds so far, refreshed twice a second so a 40 s step visibly runs. In a log or a pipe
it writes one plain line as each step starts and one as it ends. Sweep workers use none:
the sweep shows its own progress.
"""

from __future__ import annotations

import enum
import sys
import threading
import time
from typing import TextIO


class ProgressMode(enum.Enum):
    OFF = "off"
    BAR = "bar"  # a terminal: one live line
    LINES = "lines"  # a log or a pipe: plain lines

    @classmethod
    def for_stream(cls, stream: TextIO | None = None) -> ProgressMode:
        """``BAR`` when ``stream`` (default stderr) is a terminal, else ``LINES``."""
        stream = sys.stderr if stream is None else stream
        return cls.BAR if getattr(stream, "isatty", lambda: False)() else cls.LINES


def step_progress(mode: ProgressMode, stream: TextIO | None = None) -> StepProgress:
    """A `StepProgress` writing to ``stream``: by default the live line to stderr, plain
    lines to stdout (with the run's summary; stderr keeps errors alone)."""
    if stream is None:
        stream = sys.stderr if mode is ProgressMode.BAR else sys.stdout
    return StepProgress(mode, stream)


class StepProgress:
    """Start, note and end the steps of one job (see the module docstring).

    Use ``with progress.step("surface"): ...`` around each step and ``progress.note(text)``
    inside it for what the step is doing.
    """

    REFRESH_S = 0.5

    def __init__(self, mode: ProgressMode, stream: TextIO):
        self.mode, self.stream = mode, stream
        self._name = self._detail = ""
        self._start = 0.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def step(self, name: str) -> _Step:
        return _Step(self, name)

    def note(self, text: str) -> None:
        """What the current step is doing now (a live line's tail, or a plain line)."""
        if self.mode is ProgressMode.OFF:
            return
        with self._lock:
            self._detail = text
        if self.mode is ProgressMode.LINES:
            self._write(f"  {self._name}: {text}\n")

    def _begin(self, name: str) -> None:
        if self.mode is ProgressMode.OFF:
            return
        with self._lock:
            self._name, self._detail, self._start = name, "", time.perf_counter()
        if self.mode is ProgressMode.LINES:
            self._write(f"{name} ...\n")
        else:
            self._stop.clear()
            self._thread = threading.Thread(target=self._refresh, daemon=True, name="icefarm-progress")
            self._thread.start()

    def _end(self, failed: bool) -> None:
        if self.mode is ProgressMode.OFF:
            return
        seconds = time.perf_counter() - self._start
        if self.mode is ProgressMode.BAR:
            self._stop.set()
            if self._thread is not None:
                self._thread.join()
            self._write("\r\033[K")  # the live line goes; `icefarm run` prints the timings after
        else:
            self._write(f"{self._name} {'failed after' if failed else 'done in'} {seconds:.1f} s\n")

    def _refresh(self) -> None:
        while not self._stop.wait(self.REFRESH_S):
            with self._lock:
                text = f"{self._name} {time.perf_counter() - self._start:5.1f} s"
                if self._detail:
                    text += f"  {self._detail}"
            self._write("\r\033[K" + text)

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # a closed pipe must not fail the job
            pass


class _Step:
    def __init__(self, progress: StepProgress, name: str):
        self.progress, self.name = progress, name

    def __enter__(self) -> StepProgress:
        self.progress._begin(self.name)
        return self.progress

    def __exit__(self, kind, value, tb) -> None:
        self.progress._end(failed=kind is not None)
