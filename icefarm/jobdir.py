"""What a job folder holds and how its records read, in one place.

The pipeline writes a job's folder (the contract the README's job-folder section states); the sweep, the report,
the contact sheets and the CLI read it back through `read_job`. The file names, the job
states, a job's total seconds and the one line that stands for a failure are defined here
so that every reader says the same.
"""

from __future__ import annotations

import enum
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .params import flatten

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


class JobState(str, enum.Enum):
    """A job's state, as every reader tells it (and as jobs.csv and the report write it)."""

    DONE = "done"        # done.json: finished
    FAILED = "failed"    # error.json without done.json
    PENDING = "pending"  # neither: not started, running, or killed


@dataclass(frozen=True)
class JobFolder:
    """One job folder as it reads back (`read_job`); missing or damaged files read as empty.

    Attributes
    ----------
    path : Path
    state : JobState
    seconds : dict
        Step name to seconds, as timings.json (or, for a failed job, error.json) recorded them.
    reused : tuple of str
        Steps taken from the stage cache.
    stats : dict
        The rest of timings.json: input faces, icicles, ice faces, plausibility figures,
        the render's variant and seconds.
    params : dict or None
        Flat ``{"group.name": value}`` from params.yaml; None when it is missing or unreadable.
    failed_stage, message, traceback : str or None
        From error.json.
    """

    path: Path
    state: JobState
    seconds: dict = field(default_factory=dict)
    reused: tuple = ()
    stats: dict = field(default_factory=dict)
    params: dict | None = None
    failed_stage: str | None = None
    message: str | None = None
    traceback: str | None = None

    @property
    def object_id(self) -> str:
        return self.path.parent.name or "-"

    @property
    def job_id(self) -> str:
        return self.path.name

    @property
    def total_seconds(self) -> float | None:
        return total_seconds(self.seconds)


def job_state(job_dir: Path) -> JobState:
    """DONE when done.json is there, FAILED when only error.json is, PENDING otherwise."""
    job_dir = Path(job_dir)
    if (job_dir / DONE).is_file():
        return JobState.DONE
    return JobState.FAILED if (job_dir / ERROR).is_file() else JobState.PENDING


def read_job(job_dir: Path) -> JobFolder:
    """Read one job folder: its state, seconds, figures, parameters and failure."""
    job_dir = Path(job_dir)
    state = job_state(job_dir)
    params = _read_params(job_dir / PARAMS)
    if state is JobState.DONE:
        # A done job always has timings.json; done.json carries a copy of it.
        timings = read_json(job_dir / TIMINGS) or read_json(job_dir / DONE)
        return JobFolder(job_dir, state, _mapping(timings.get("seconds")),
                         tuple(str(s) for s in timings.get("reused") or ()),
                         {k: v for k, v in timings.items() if k not in ("seconds", "reused", "job", "artifacts")},
                         params)
    if state is JobState.FAILED:
        error = read_json(job_dir / ERROR)
        return JobFolder(job_dir, state, _mapping(error.get("seconds")), (), {}, params,
                         str(error.get("stage") or "-"), str(error.get("message") or "unreadable error.json"),
                         str(error["traceback"]) if error.get("traceback") else None)
    return JobFolder(job_dir, state, params=params)


def read_json(path: Path) -> dict:
    """A JSON object from ``path``; empty when missing, unreadable or not an object."""
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def _read_params(path: Path) -> dict | None:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return flatten(data) if isinstance(data, Mapping) else None


def _mapping(value: Any) -> dict:
    return dict(value) if isinstance(value, Mapping) else {}
