"""One job as a farm worker gets it (`Task`), how the worker runs it (`execute`), and what
both backends share: the order tasks are handed out in (`Gate`), the cores a worker gets,
and the error.json of a job that failed outside the pipeline.

Both backends (`local`, `dask_backend`) take the same `Task` list and report each job's
`JobOutcome` through a callback as it finishes. A job's failure is the pipeline's business
(it writes error.json and returns "failed"); what the backends handle is a worker dying under
a job (killed, out of memory, a crash in native code).

This module imports nothing heavy at the top: a spawned worker imports it before its
initializer runs, and the thread settings must come first.
"""

from __future__ import annotations

import os
import shutil
import traceback
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..jobdir import JobState


@dataclass(frozen=True)
class Task:
    """One job as a worker receives it.

    Attributes
    ----------
    spec : icefarm.job.pipeline.JobSpec
    job_id, object_id : str
    job_dir : str
        Folder the job writes; emptied before each attempt.
    cache_dir : str or None
        Stage cache shared by the sweep.
    until : str or None
        Last stage to run (a `Stage` value).
    running_dir : str
        Where the worker leaves ``<job id>.pid`` (one line per attempt) while it runs.
    threads : int or None
        Dr.Jit / BLAS threads for the worker (its share of the cores).
    """

    spec: Any
    job_id: str
    object_id: str
    job_dir: str
    cache_dir: str | None
    until: str | None
    running_dir: str
    threads: int | None = None


OnOutcome = Callable[[Task, Any, int], None]  # on_outcome(task, outcome, attempts), as each job ends


# --------------------------------------------------------------------------- in the worker

def marker_path(task: Task) -> Path:
    """``<job id>.pid`` in the running folder: one line (a worker's pid) per attempt started."""
    return Path(task.running_dir) / f"{task.job_id}.pid"


def _add_attempt(marker: Path) -> None:
    """Add this worker's pid to ``marker`` as a line of its own (a leftover line means a dead
    worker), replacing the file whole: whoever reads it (the driver, a monitor, the fault
    tests) never finds it created but not yet written. One worker runs a job at a time."""
    marker.parent.mkdir(parents=True, exist_ok=True)
    try:
        before = marker.read_text()
    except FileNotFoundError:
        before = ""
    tmp = marker.with_name(f".{marker.name}.{os.getpid()}")
    tmp.write_text(f"{before}{os.getpid()}\n")
    os.replace(tmp, marker)


def attempts_started(task: Task) -> int:
    """How many times a worker started ``task`` in this sweep run without finishing it yet."""
    try:
        return len(marker_path(task).read_text().split())
    except OSError:
        return 0


def failed_outcome(message: str, stage: str | None = None, trace: str = ""):
    """A `JobOutcome` for a job that the farm, not the pipeline, saw fail."""
    from ..job.pipeline import JobOutcome

    return JobOutcome(status=JobState.FAILED, seconds={}, reused=(), failed_stage=stage,
                      error=message + ("\n" + trace if trace else ""))


def write_error(job_dir: str | Path, message: str, stage: str | None = None, trace: str = "") -> None:
    """error.json as the pipeline writes it, for failures outside the pipeline."""
    from ..artifacts import write_json
    from ..jobdir import ERROR

    write_json(Path(job_dir) / ERROR, {"stage": stage, "message": message, "traceback": trace})


def execute(task: Task, defer_render: bool = False) -> tuple[Any, int]:
    """Run one job in this worker process; with ``defer_render``, its stages only when its
    render can run apart (`icefarm.job.pipeline.renders_apart`: status ``pending`` until
    `execute_render`).

    Returns
    -------
    outcome : JobOutcome
    attempt : int
        1 for the first start of the job, 2 after a worker died under it, ...
    """
    marker = marker_path(task)
    _add_attempt(marker)
    attempt = attempts_started(task)
    job_dir = Path(task.job_dir)
    if job_dir.is_symlink():  # a link someone made: the job gets its own folder, the target stays as it is
        job_dir.unlink()
    elif job_dir.exists():  # leftovers of an attempt that did not finish
        shutil.rmtree(job_dir)
    job_dir.mkdir(parents=True)
    try:
        from ..job import pipeline

        if task.spec.render is not None and task.threads and not defer_render:
            _render_threads(task.threads)
        until = pipeline.Stage(task.until) if task.until else None
        cache = Path(task.cache_dir) if task.cache_dir else None
        outcome = pipeline.run_job(task.spec, job_dir, cache_dir=cache, until=until, defer_render=defer_render,
                                   measure_beside=not task.threads or task.threads > 1)
    except Exception as exc:  # run_job reports job failures itself; this is a farm-level bug
        trace = traceback.format_exc()
        write_error(job_dir, f"{type(exc).__name__}: {exc}", None, trace)
        outcome = failed_outcome(f"{type(exc).__name__}: {exc}", None, trace)
    marker.unlink(missing_ok=True)
    return outcome, attempt


def execute_geometry(task: Task) -> tuple[Any, int]:
    """A job's stages, its render left for `execute_render` (a farm's render workers)."""
    return execute(task, defer_render=True)


def execute_render(task: Task, geometry: tuple[Any, int]) -> tuple[Any, int]:
    """Render a job whose stages `execute_geometry` ran (``geometry``: its outcome and
    attempt) and finish it; a job whose stages failed stays failed, untouched."""
    outcome, attempt = geometry
    if outcome.status is not JobState.PENDING:
        return outcome, attempt
    try:
        from ..job import pipeline

        if task.threads:
            _render_threads(task.threads)
        outcome = pipeline.finish_render(task.spec, Path(task.job_dir))
    except Exception as exc:  # finish_render reports job failures itself; this is a farm-level bug
        trace = traceback.format_exc()
        write_error(task.job_dir, f"{type(exc).__name__}: {exc}", "render", trace)
        outcome = failed_outcome(f"{type(exc).__name__}: {exc}", "render", trace)
    return outcome, attempt


def _render_threads(threads: int) -> None:
    from ..scene.variants import set_thread_count

    set_thread_count(threads)


# --------------------------------------------------------------------------- scheduling

class Gate:
    """Hands out tasks in order, holding back each task until the one it waits for is done."""

    def __init__(self, tasks: Sequence[Task], waits: Mapping[str, str]):
        self.queue = deque(tasks)
        self.waits = dict(waits)
        self.finished: set[str] = set()

    def __bool__(self) -> bool:
        return bool(self.queue)

    def next(self) -> Task | None:
        for i, task in enumerate(self.queue):
            leader = self.waits.get(task.job_id)
            if leader is None or leader in self.finished:
                del self.queue[i]
                return task
        return None

    def requeue(self, task: Task) -> None:
        self.queue.appendleft(task)

    def finish(self, task: Task) -> None:
        self.finished.add(task.job_id)


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def threads_per_worker(workers: int) -> int:
    """Threads each of ``workers`` workers gets: its share of `cores`, at least one."""
    return max(1, cores() // max(1, workers))

