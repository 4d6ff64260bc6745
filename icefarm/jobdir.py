"""What a job folder holds and how its records read, in one place.

The pipeline writes a job's folder (DESIGN.md's artifact contract); the sweep, the report,
the contact sheets and the CLI read it back. The file names, a job's total seconds and the
one line that stands for a failure are defined here so that every reader says the same.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

DONE = "done.json"          # written last, atomically: the job finished
ERROR = "error.json"        # {"stage", "message", "traceback"}: the job failed
TIMINGS = "timings.json"    # {"seconds": {step: s}, ...plausibility figures}
PARAMS = "params.yaml"      # the resolved parameters the job ran with


def total_seconds(seconds: Any) -> float | None:
    """Sum of a job's recorded step times (``timings.json``'s or ``error.json``'s ``seconds``:
    preparation, proxy, stages with their cache loads, render, export); None when it holds
    no number. Booleans are not seconds."""
    if not isinstance(seconds, Mapping):
        return None
    values = [float(v) for v in seconds.values() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return sum(values) if values else None


def stage_phrase(stage: str | None) -> str:
    """Where a job failed, for a sentence: ``in stage surface``, or ``after stage
    trajectories`` for a failure between steps (the pipeline records ``after <step>``)."""
    if not stage:
        return "in an unknown stage"
    return f"after stage {stage[6:]}" if stage.startswith("after ") else f"in stage {stage}"


def error_line(message: Any, default: str = "-") -> str:
    """The line that stands for a failure in tables and cells: the first non-empty line of
    its message, which names the exception (``ValueError: ...``) where the pipeline wrote
    it; later lines are detail."""
    for line in str(message or "").splitlines():
        if line.strip():
            return line.strip()
    return default
