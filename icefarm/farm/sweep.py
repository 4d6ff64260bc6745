"""Expand a manifest's sweep into jobs, run them on a backend, and lay out the sweep folder.

::

    <out>/<sweep name>/
      manifest.resolved.yaml    the manifest after defaults, --set and expansion (every job listed)
      jobs/<object id>/<job id>/ one job's artifacts (the pipeline fills it; done.json last)
      jobs.csv                  job id, object, swept values, status, seconds, reused stages, ...
      cache/                    stage results shared by the jobs of the sweep
      .farm/running/            one marker per job being run: the worker's pid (crash attribution)
    <out>/.<sweep name>.lock    held (flock) by the sweep writing the folder: a second one is refused

Jobs of one object that share the water stage wait for the first of them, so that a sweep
over later stages computes the early stages once and reuses them from the cache; jobs of
other objects run meanwhile.
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

from ..artifacts import atomic_write
from ..errors import InputError, Interrupted, cannot_write
from ..jobdir import (
    CACHE_DIR,
    DONE,
    JOBS_CSV,
    JOBS_DIR,
    MANIFEST,
    JobState,
    check_done,
    read_job,
    read_jobs_csv,
    total_seconds,
)
from .manifest import load_manifest
from .manifest_model import Manifest
from .plan import JobRecord, PlannedJob, leaders, manifest_warnings, plan_jobs, private_stages
from .points import MAX_JOBS, apply_sets, check_job_count, swept_keys
from .sweep_folder import check_folder, job_dir, jobs_csv_text, prepare_folder, resolved_yaml, stale_folders, sweep_lock

CSV_INTERVAL_S = 2.0  # jobs.csv is rewritten at most this often while a sweep runs, and at its end


@dataclass(frozen=True)
class SweepSummary:
    """The result of `run_sweep`: what the CLI prints and what sheets and reports build on."""

    name: str
    sweep_dir: Path
    jobs: tuple[JobRecord, ...]
    swept: tuple[str, ...]
    wall_seconds: float
    backend: str
    workers: int
    dry_run: bool = False
    duplicates: int = 0
    stale: tuple[Path, ...] = ()

    @property
    def done(self) -> int:
        return sum(r.status == JobState.DONE for r in self.jobs)

    @property
    def failed(self) -> int:
        return sum(r.status == JobState.FAILED for r in self.jobs)

    @property
    def pending(self) -> int:
        return sum(r.status == JobState.PENDING for r in self.jobs)

    @property
    def resumed(self) -> int:
        return sum(r.resumed for r in self.jobs)

    @property
    def reused(self) -> int:
        """Stage results taken from the cache instead of computed, over all jobs run."""
        return sum(len(r.reused) for r in self.jobs if not r.resumed)

    @property
    def retried(self) -> int:
        return sum(r.attempts > 1 and not r.resumed for r in self.jobs)

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.pending == 0

    @property
    def jobs_csv(self) -> Path:
        return self.sweep_dir / JOBS_CSV


class Progress(Protocol):
    """Receives a sweep's progress (a tqdm bar, plain lines, or nothing)."""

    def start(self, total: int, already_done: int, workers: int | None = None) -> None: ...

    def update(self, record: JobRecord) -> None: ...

    def close(self) -> None: ...

    # Optional: ``note(text)`` for a message that is not a job's (a job folder that will be
    # redone, stale folders, a Dask cluster waiting for workers).


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """While a sweep runs in the main thread, SIGTERM and SIGHUP raise `Interrupted` as
    Ctrl-C does (SIGINT too, as `Interrupted`), so that the backends end their workers and
    the lock goes; a second signal meanwhile ends the process at once (its local workers
    follow it: `local._worker_init`). Signals this process ignores (``nohup``) stay
    ignored. Elsewhere than in the main thread, nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    wanted = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    previous = {s: signal.getsignal(s) for s in wanted}
    mine = [s for s, h in previous.items() if h in (signal.SIG_DFL, signal.default_int_handler)]

    def handler(signum, frame):
        for s in mine:
            signal.signal(s, signal.SIG_DFL)
        raise Interrupted(signum)

    for s in mine:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s in mine:
            signal.signal(s, previous[s])


def _stderr_note(text: str) -> None:
    print(f"note: {text}", file=sys.stderr, flush=True)


def _stderr_warning(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- running

@dataclass(frozen=True)
class SweepOptions:
    """How `run_sweep` runs a manifest's jobs.

    Attributes
    ----------
    workers : int
        Worker processes (local) or LocalCluster workers (dask without ``scheduler``).
    backend : {"local", "dask"}
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); dask backend only.
    sets : sequence of str
        ``group.param=value`` (fixed) or ``group.param=v1,v2`` (swept) overrides.
    resume, overwrite : bool
        What to do with an existing sweep folder: finish its jobs (done ones are skipped,
        half-written ones, and done ones whose artifacts changed, are redone), or delete it.
        Without either an existing folder is refused.
    dry_run : bool
        Plan only: nothing is written or run; jobs already done are reported as done.
    render : bool
        False runs no render (``--no-render``).
    until : str, optional
        Last stage to run (``water``, ``drips``, ``trajectories``, ``surface``, ``render``).
    max_tasks_per_child : int
        Local workers are replaced after this many jobs (Mitsuba's memory grows per process).
    use_cache : bool
        Share stage results between the jobs through ``<sweep>/cache``.
    max_jobs : int or None
        Refuse a sweep of more jobs (counted before anything is expanded); None: no limit.
    connect_timeout : float
        Seconds to reach a Dask ``scheduler``.
    """

    workers: int = 1
    backend: str = "local"
    scheduler: str | None = None
    sets: Sequence[str] = ()
    resume: bool = False
    overwrite: bool = False
    dry_run: bool = False
    render: bool = True
    until: str | None = None
    max_tasks_per_child: int = 8
    use_cache: bool = True
    max_jobs: int | None = MAX_JOBS
    connect_timeout: float = 30.0

    def check(self) -> None:
        """Refuse options that cannot run, in one line each (`InputError`)."""
        from .dask_backend import check_scheduler_address

        if self.backend not in ("local", "dask"):
            raise InputError(f"unknown backend {self.backend!r}: expected local or dask")
        if self.scheduler and self.backend != "dask":
            raise InputError("--scheduler needs --backend dask")
        if self.scheduler:
            check_scheduler_address(self.scheduler)
        if self.workers < 1:
            raise InputError(f"--workers must be at least 1, got {self.workers}")
        if self.until is not None:
            from ..job import Stage

            try:
                Stage(self.until)
            except ValueError:
                raise InputError(f"unknown stage {self.until!r}: expected one of "
                                 f"{', '.join(s.value for s in Stage)}") from None


def run_sweep(manifest: Manifest | str | Path, out: str | Path = "out", options: SweepOptions | None = None, *,
              progress: Progress | None = None, note: Callable[[str], None] | None = None,
              warn: Callable[[str], None] | None = None) -> SweepSummary:
    """Run every job of a manifest's sweep and return what became of them.

    Parameters
    ----------
    manifest : Manifest or path
        A validated manifest, or the path of one (validated here).
    out : path
        The sweep folder is ``out/<manifest name>``.
    options : SweepOptions, optional
        Workers, backend, what to do with an existing folder, how far to run; the defaults
        without.
    progress : Progress, optional
        Told when the sweep starts and after every job.
    note : callable, optional
        ``note(text)`` for messages that are not a job's (folders to redo, stale folders,
        a cluster waiting for workers); default: ``progress.note``, else stderr.
    warn : callable, optional
        ``warn(text)`` for what a valid manifest may not mean (`plan.manifest_warnings`: knobs
        its storm mode ignores, unlikely sizes), once each, after every check has passed;
        default: ``warning: TEXT`` on stderr.

    Returns
    -------
    SweepSummary

    Raises
    ------
    InputError
        An invalid manifest or ``--set``, too many jobs, an existing or unwritable output
        folder, an unknown backend, a bad or unreachable scheduler; nothing is written then.
    Interrupted
        SIGINT, SIGTERM or SIGHUP (main thread only): the workers were ended, jobs.csv
        written; its ``summary`` says what was done.
    """
    o = options or SweepOptions()
    started = time.perf_counter()
    if note is None:
        note = getattr(progress, "note", None) or _stderr_note
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    manifest = apply_sets(manifest, o.sets)
    o.check()
    check_job_count(manifest, o.max_jobs)
    jobs, duplicates = plan_jobs(manifest, render=o.render)
    swept = swept_keys(manifest.sweep)
    sweep_dir = Path(out).expanduser().resolve() / manifest.name
    records = {j.job_id: JobRecord(job_id=j.job_id, object_id=j.object_id, values=j.values,
                                   job_dir=job_dir(sweep_dir, j)) for j in jobs}
    stale = _earlier_run(records, jobs, sweep_dir, o.dry_run, note) if o.resume or o.dry_run else []

    def summary() -> SweepSummary:
        return SweepSummary(name=manifest.name, sweep_dir=sweep_dir, jobs=tuple(records.values()),
                            swept=swept, wall_seconds=time.perf_counter() - started, backend=o.backend,
                            workers=o.workers, dry_run=o.dry_run, duplicates=duplicates, stale=tuple(stale))

    def warn_once() -> None:  # once the sweep is sure to run: an error stays alone on its line
        for line in manifest_warnings(manifest):
            (warn or _stderr_warning)(line)

    if o.dry_run:
        warn_once()
        return summary()
    todo = [j for j in jobs if records[j.job_id].status != JobState.DONE]
    check_folder(sweep_dir, o.resume, o.overwrite)
    from .dask_backend import dask_client

    # A cluster is reached before anything is written: an unreachable one leaves nothing behind.
    cluster = (dask_client(o.workers, o.scheduler, connect_timeout=o.connect_timeout)
               if o.backend == "dask" and todo else contextlib.nullcontext())
    with stop_on_signals(), cluster as client, sweep_lock(sweep_dir):
        cache_dir = _open_folder(sweep_dir, manifest, jobs, records, swept, o, note)
        warn_once()
        _run_jobs(todo, jobs, records, _Run(sweep_dir, cache_dir, swept, o, progress, client, note), summary)
        shutil.rmtree(sweep_dir / ".farm", ignore_errors=True)
    return summary()


def _earlier_run(records: dict[str, JobRecord], jobs: Sequence[PlannedJob], sweep_dir: Path, dry_run: bool,
                 note: Callable[[str], None]) -> list[Path]:
    """Mark the jobs an earlier run finished as done (in ``records``); say which folders are
    redone and which are stale (returned)."""
    earlier = {row["job_id"]: row for row in read_jobs_csv(sweep_dir / JOBS_CSV)[0]}
    for j in jobs:
        path = records[j.job_id].job_dir
        why = check_done(path)
        if why is None:  # the attempts it took, as the earlier run's jobs.csv has them
            attempts = earlier.get(j.job_id, {}).get("attempts", "")
            records[j.job_id] = replace(records[j.job_id], status=JobState.DONE, resumed=True,
                                        seconds=read_job(path).total_seconds or 0.0,
                                        attempts=max(1, int(attempts) if attempts.isdigit() else 1))
        elif path.is_dir() and why != f"no {DONE}":
            note(f"{path.relative_to(sweep_dir)}: {why}: {'would be' if dry_run else 'it is'} redone")
    stale = stale_folders(sweep_dir, jobs)
    if stale:
        shown = ", ".join(str(p.relative_to(sweep_dir)) for p in stale[:10])
        more = f" and {len(stale) - 10} more" if len(stale) > 10 else ""
        note(f"{len(stale)} job folder(s) in {sweep_dir / JOBS_DIR} are not jobs of this manifest (it was "
             f"edited since they were made, or --set differs); they are stale and left as they are: "
             f"{shown}{more}")
    return stale


def _open_folder(sweep_dir: Path, manifest: Manifest, jobs: Sequence[PlannedJob], records: dict[str, JobRecord],
                 swept: tuple[str, ...], o: SweepOptions, note: Callable[[str], None]) -> Path | None:
    """The sweep folder made ready to run (its resolved manifest, jobs.csv, the cache's
    policy); its cache folder, None without. A folder that cannot be written is one line,
    and a folder this run made is removed again."""
    prepare_folder(sweep_dir, o.resume, o.overwrite)
    made = not sweep_dir.exists()  # by this run: removed again when it cannot be written
    cache_dir = sweep_dir / CACHE_DIR if o.use_cache else None
    running = sweep_dir / ".farm" / "running"
    try:
        shutil.rmtree(running, ignore_errors=True)  # markers of an earlier run that was stopped
        running.mkdir(parents=True, exist_ok=True)
        if cache_dir is not None:
            from ..job.cache import write_policy

            if not write_policy(cache_dir, private_stages(jobs)):
                note(f"the stage cache {cache_dir} is read-only: its results are reused, "
                     "the others computed and not stored")
        atomic_write(sweep_dir / MANIFEST, resolved_yaml(manifest, jobs, sweep_dir, o.until))
        atomic_write(sweep_dir / JOBS_CSV, jobs_csv_text(list(records.values()), swept))
    except OSError as exc:
        if made:
            shutil.rmtree(sweep_dir, ignore_errors=True)  # nothing half-made left behind
        raise cannot_write(exc, f"the sweep folder {sweep_dir}") from None
    return cache_dir


@dataclass(frozen=True)
class _Run:
    """Where and how a sweep's jobs run (`_run_jobs`)."""

    sweep_dir: Path
    cache_dir: Path | None
    swept: tuple[str, ...]
    options: SweepOptions
    progress: Progress | None
    client: object
    note: Callable[[str], None]


def _run_jobs(todo: Sequence[PlannedJob], jobs: Sequence[PlannedJob], records: dict[str, JobRecord], run: _Run,
              summary: Callable[[], SweepSummary]) -> None:
    """Run ``todo`` on the backend, recording each outcome in ``records`` and jobs.csv;
    a signal ends the workers and raises `Interrupted` carrying the ``summary``."""
    from .dask_backend import run_dask
    from .local import run_local
    from .task import Task

    o, progress, csv_path = run.options, run.progress, run.sweep_dir / JOBS_CSV
    running = run.sweep_dir / ".farm" / "running"
    tasks = [Task(spec=j.spec, job_id=j.job_id, object_id=j.object_id, job_dir=str(records[j.job_id].job_dir),
                  cache_dir=str(run.cache_dir) if run.cache_dir else None, until=o.until,
                  running_dir=str(running)) for j in todo]
    # A job whose leader is already done (resume) need not wait for anything.
    # Without a cache there is nothing to wait for.
    waits = {k: v for k, v in leaders(jobs).items() if records[v].status != JobState.DONE} if o.use_cache else {}
    last_write = [time.monotonic()]

    def on_outcome(task, outcome, attempts: int) -> None:
        records[task.job_id] = replace(
            records[task.job_id], status=outcome.status,
            seconds=total_seconds(outcome.seconds) or 0.0, reused=tuple(outcome.reused),
            attempts=attempts, failed_stage=outcome.failed_stage, error=outcome.error)
        if time.monotonic() - last_write[0] > CSV_INTERVAL_S:  # rewriting it per job is quadratic
            atomic_write(csv_path, jobs_csv_text(list(records.values()), run.swept))
            last_write[0] = time.monotonic()
        if progress is not None:
            progress.update(records[task.job_id])

    if progress is not None:
        # a scheduler's workers are its own: how many run at once is not known here
        progress.start(len(jobs), len(jobs) - len(todo), None if o.scheduler else o.workers)
    stopped: Interrupted | None = None
    try:
        if tasks and o.backend == "local":
            run_local(tasks, workers=o.workers, on_outcome=on_outcome, waits=waits,
                      max_tasks_per_child=o.max_tasks_per_child)
        elif tasks:
            run_dask(tasks, workers=o.workers, scheduler=o.scheduler, on_outcome=on_outcome,
                     waits=waits, client=run.client, note=run.note)
    except KeyboardInterrupt as exc:  # the workers are gone (the backends saw to it)
        stopped = exc if isinstance(exc, Interrupted) else Interrupted(signal.SIGINT)
    finally:
        if progress is not None:
            progress.close()
        atomic_write(csv_path, jobs_csv_text(list(records.values()), run.swept))
    if stopped is not None:
        stopped.summary = summary()
        raise stopped
