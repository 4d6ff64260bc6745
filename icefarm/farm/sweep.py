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
import csv
import enum
import hashlib
import io
import json
import os
import shutil
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import yaml

from .. import params as P
from ..artifacts import atomic_write, check_done
from ..errors import InputError, Interrupted, short_repr
from ..jobdir import TIMINGS, error_line, total_seconds
from .manifest import Manifest, load_manifest, manifest_to_dict
from .points import MAX_JOBS, apply_sets, check_job_count, expand, swept_keys

# The parameter groups each early stage reads: jobs that agree on them share that stage.
WATER_GROUPS = ("water", "proxy")
CSV_INTERVAL_S = 2.0  # jobs.csv is rewritten at most this often while a sweep runs, and at its end
# What each stage's result depends on besides the object (its mesh, size, seed, overrides):
# jobs of one object that agree on these groups may share the stage (its cache key holds
# them, and more). A stage that no two jobs of a sweep can share is not stored in its cache.
STAGE_GROUPS = (("proxy", ()), ("water", ("water",)), ("drips", ("water", "drips")),
                ("trajectories", ("water", "drips", "trajectories")),
                ("surface", ("water", "drips", "trajectories", "surface", "glaze", "ground_ice")))


class Status(enum.Enum):
    """Job states, as jobs.csv writes them."""

    PENDING = "pending"
    DONE = "done"
    FAILED = "failed"


@dataclass(frozen=True)
class PlannedJob:
    """One (object, sweep point) pair, ready to run.

    Attributes
    ----------
    spec : icefarm.pipeline.JobSpec
    job_id : str
        ``pipeline.job_id(spec)``; the job's folder name.
    object_id : str
    values : tuple
        ``((key, value), ...)``: this job's swept values, in sweep order.
    """

    spec: Any
    job_id: str
    object_id: str
    values: tuple


@dataclass(frozen=True)
class JobRecord:
    """What became of one job.

    Attributes
    ----------
    status : Status
        ``done``, ``failed`` or ``pending`` (not run: a dry run, or an interrupted sweep).
    seconds : float
        Wall time the worker spent on the job (sum of the stage times), 0 when not run.
    reused : tuple of str
        Stages taken from the cache.
    attempts : int
        Times the job was started (2 after a worker died under it).
    resumed : bool
        Already done before this run (``--resume``); not run again.
    """

    job_id: str
    object_id: str
    values: tuple
    job_dir: Path
    status: Status = Status.PENDING
    seconds: float = 0.0
    reused: tuple = ()
    attempts: int = 0
    resumed: bool = False
    failed_stage: str | None = None
    error: str | None = None


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
        return sum(r.status == Status.DONE for r in self.jobs)

    @property
    def failed(self) -> int:
        return sum(r.status == Status.FAILED for r in self.jobs)

    @property
    def pending(self) -> int:
        return sum(r.status == Status.PENDING for r in self.jobs)

    @property
    def resumed(self) -> int:
        return sum(r.resumed for r in self.jobs)

    @property
    def reused(self) -> int:
        """Stage results taken from the cache instead of computed, over all jobs run."""
        return sum(len(r.reused) for r in self.jobs if not r.resumed)

    @property
    def retried(self) -> int:
        return sum(r.attempts > 1 for r in self.jobs)

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.pending == 0

    @property
    def jobs_csv(self) -> Path:
        return self.sweep_dir / "jobs.csv"


class Progress(Protocol):
    """Receives a sweep's progress (a tqdm bar, plain lines, or nothing)."""

    def start(self, total: int, already_done: int) -> None: ...

    def update(self, record: JobRecord) -> None: ...

    def close(self) -> None: ...

    # Optional: ``note(text)`` for a message that is not a job's (a job folder that will be
    # redone, stale folders, a Dask cluster waiting for workers).


# --------------------------------------------------------------------------- jobs

def job_seed(manifest_seed: int, object_id: str) -> int:
    """The seed of every job of one object: stable, from the manifest seed and the object id.

    All sweep points of an object share it, so that the stages a point does not change
    (water, drips, trajectories when sweeping the surface) are the same results, reused from
    the cache, and a contact sheet compares like with like.
    """
    digest = hashlib.sha256(f"icefarm:{manifest_seed}:{object_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def plan_jobs(manifest: Manifest, render: bool = True) -> tuple[tuple[PlannedJob, ...], int]:
    """One job per (object, sweep point), objects in manifest order, points in sweep order.

    Parameters
    ----------
    manifest : Manifest
    render : bool
        False drops the render config from every job (``--no-render``).

    Returns
    -------
    jobs : tuple of PlannedJob
    duplicates : int
        Points dropped because they repeat an earlier job exactly (same job id).

    Raises
    ------
    InputError
        A sweep point puts a parameter out of its domain together with the others.
    """
    from ..pipeline import JobSpec, job_id

    points = expand(manifest.sweep, manifest.seed)
    keys = swept_keys(manifest.sweep)
    jobs, seen, duplicates = [], set(), 0
    for obj in manifest.objects:
        for point in points:
            try:
                resolved = P.resolve(manifest.defaults, obj.params, point, manifest.fixed)
            except InputError as exc:
                raise InputError(f"{manifest.path}: object {obj.id}, sweep point {short_repr(point)}: "
                                 f"{exc}") from None
            spec = JobSpec(object_id=obj.id, mesh=obj.mesh, size_m=obj.size_m, params=resolved,
                           seed=job_seed(manifest.seed, obj.id),
                           render=manifest.render if render else None,
                           exclude=obj.exclude, overrides=obj.overrides, material=obj.material,
                           placement=obj.placement)
            jid = job_id(spec)
            if jid in seen:
                duplicates += 1
                continue
            seen.add(jid)
            jobs.append(PlannedJob(spec=spec, job_id=jid, object_id=obj.id,
                                   values=tuple((k, point[k]) for k in keys)))
    return tuple(jobs), duplicates


def leaders(jobs: Sequence[PlannedJob]) -> dict[str, str]:
    """``{job id: id of the earlier job it waits for}``.

    Jobs of one object that agree on the water stage's inputs wait for the first of them:
    once it is done, its stage results are in the cache and the others reuse them instead of
    computing them again in parallel. Jobs with a different water stage do not wait.
    """
    first: dict[str, str] = {}
    out: dict[str, str] = {}
    for job in jobs:
        spec = job.spec
        water = {g: spec.params.get(g) for g in WATER_GROUPS}
        key = json.dumps([job.object_id, water, [list(o) for o in spec.overrides]], sort_keys=True, default=str)
        if key in first:
            out[job.job_id] = first[key]
        else:
            first[key] = job.job_id
    return out


# --------------------------------------------------------------------------- the sweep folder

def private_stages(jobs: Sequence[PlannedJob]) -> list[str]:
    """Stages whose result no two of ``jobs`` can share (`STAGE_GROUPS`).

    The sweep's cache does not store them (``cache/policy.json``): a sweep over surface
    parameters would otherwise pickle every job's ice surface, which no other job reads.
    Jobs are compared on fewer inputs than the cache keys hold, so a stage that two jobs
    might share is always stored.
    """
    out = []
    for stage, groups in STAGE_GROUPS:
        signatures = Counter(json.dumps([j.object_id, [j.spec.params.get(g) for g in groups]],
                                        sort_keys=True, default=str) for j in jobs)
        if signatures and max(signatures.values()) == 1:
            out.append(stage)
    return out


def job_dir(sweep_dir: Path, job: PlannedJob) -> Path:
    return sweep_dir / "jobs" / job.object_id / job.job_id


def is_done(path: Path) -> bool:
    """The job in ``path`` finished and its artifacts are as done.json lists them."""
    return check_done(path) is None


def stale_folders(sweep_dir: Path, jobs: Sequence[PlannedJob]) -> list[Path]:
    """Job folders in ``sweep_dir/jobs`` that are no job of ``jobs`` (an edited manifest)."""
    planned = {job_dir(sweep_dir, j) for j in jobs}
    root = sweep_dir / "jobs"
    if not root.is_dir():
        return []
    return sorted(p for p in root.glob("*/*") if p.is_dir() and p not in planned)


def _format(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return " ".join(_format(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def jobs_csv_text(records: Sequence[JobRecord], swept: Sequence[str]) -> str:
    """jobs.csv: one row per job, the swept values in their own columns."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["job_id", "object", *swept, "status", "seconds", "reused", "attempts",
                     "failed_stage", "error"])
    for r in records:
        values = dict(r.values)
        writer.writerow([r.job_id, r.object_id, *(_format(values.get(k, "")) for k in swept), r.status.value,
                         f"{r.seconds:.3f}", " ".join(r.reused), r.attempts, r.failed_stage or "",
                         error_line(r.error, "")])
    return buf.getvalue()


def _resolved_yaml(manifest: Manifest, jobs: Sequence[PlannedJob], sweep_dir: Path, until: str | None) -> str:
    data = manifest_to_dict(manifest)
    data["until"] = until
    data["jobs"] = [{"id": j.job_id, "object": j.object_id, "seed": j.spec.seed,
                     "dir": str(job_dir(sweep_dir, j).relative_to(sweep_dir)),
                     "values": {k: v for k, v in j.values}} for j in jobs]
    return yaml.safe_dump(data, sort_keys=False)


def _previous_seconds(path: Path) -> float:
    """Seconds recorded by a finished job (timings.json), for resumed rows of jobs.csv."""
    try:
        data = json.loads((path / TIMINGS).read_text())
    except (OSError, ValueError):
        return 0.0
    return total_seconds(data.get("seconds", data) if isinstance(data, Mapping) else None) or 0.0


def check_folder(sweep_dir: Path, resume: bool, overwrite: bool) -> bool:
    """Refuse what `prepare_folder` would refuse, deleting nothing; True when there is an
    existing sweep folder to keep (resume) or to delete (overwrite)."""
    if resume and overwrite:
        raise InputError("--resume and --overwrite exclude each other: resume keeps the done jobs, "
                         "overwrite deletes them")
    if sweep_dir.is_symlink():
        target = os.readlink(sweep_dir)
        if not sweep_dir.exists():
            raise InputError(f"output {sweep_dir} is a symbolic link to {target}, which does not exist: "
                             "remove the link or choose another -o")
        if overwrite:
            raise InputError(f"refusing to overwrite {sweep_dir}: it is a symbolic link (to {target}); "
                             "delete the link or what it points to yourself, or choose another -o")
    try:
        if not sweep_dir.exists() or (sweep_dir.is_dir() and not any(sweep_dir.iterdir())):
            return False
    except OSError as exc:
        raise InputError(f"cannot read the output folder {sweep_dir}: {exc.strerror or exc}") from None
    if not sweep_dir.is_dir():
        raise InputError(f"output {sweep_dir} exists and is not a folder")
    if resume:
        return
    if not overwrite:
        raise InputError(f"output folder {sweep_dir} already exists: add --resume to finish its jobs "
                         f"(done ones are kept), --overwrite to delete it and start over, or choose -o")
    if not ((sweep_dir / "manifest.resolved.yaml").exists() or (sweep_dir / "jobs").is_dir()):
        raise InputError(f"refusing to overwrite {sweep_dir}: it does not look like an icefarm sweep folder "
                         f"(no manifest.resolved.yaml, no jobs/); remove it yourself or choose another -o")
    return True


def prepare_folder(sweep_dir: Path, resume: bool, overwrite: bool) -> None:
    """Refuse an existing sweep folder unless resuming; clear it for ``overwrite``."""
    if check_folder(sweep_dir, resume, overwrite) and overwrite:
        try:
            shutil.rmtree(sweep_dir)
        except OSError as exc:
            raise InputError(f"--overwrite: cannot delete {exc.filename or sweep_dir}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def sweep_lock(sweep_dir: Path) -> Iterator[None]:
    """Hold ``<out>/.<sweep name>.lock`` while this process writes ``sweep_dir``.

    A second sweep on the same folder (``--resume`` or ``--overwrite`` while the first runs)
    would delete the first's jobs under its workers; it is refused instead. The lock is a
    ``flock``: the system drops it when its process dies, so a killed sweep leaves none.
    The file sits beside the folder, which ``--overwrite`` deletes.

    Raises
    ------
    InputError
        Another process holds the lock.
    """
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    lock = sweep_dir.parent / f".{sweep_dir.name}.lock"
    try:
        sweep_dir.parent.mkdir(parents=True, exist_ok=True)
        fh = open(lock, "a+")
    except OSError as exc:
        raise InputError(f"cannot write the output folder {sweep_dir.parent}: "
                         f"{exc.strerror or exc} ({exc.filename or lock})") from None
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            raise InputError(f"another icefarm sweep (pid {holder}) is writing {sweep_dir}: wait for it "
                             "to end (then --resume), or choose another -o") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        try:
            yield
        finally:
            fh.truncate(0)  # an empty lock file names nobody
            fcntl.flock(fh, fcntl.LOCK_UN)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """While a sweep runs in the main thread, SIGTERM and SIGHUP raise `Interrupted` as
    Ctrl-C does (SIGINT too, as `Interrupted`), so that the backends end their workers and
    the lock goes; a second signal meanwhile ends the process at once (its local workers
    follow it: `backends._worker_init`). Signals this process ignores (``nohup``) stay
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


def _os_error(exc: OSError, what: str) -> InputError:
    return InputError(f"cannot write {what}: {exc.strerror or exc} ({exc.filename or what})")


# --------------------------------------------------------------------------- running

def run_sweep(manifest: Manifest | str | Path, out: str | Path = "out", *, workers: int = 1,
              backend: str = "local", scheduler: str | None = None, sets: Sequence[str] = (),
              resume: bool = False, overwrite: bool = False, dry_run: bool = False,
              render: bool = True, until: str | None = None, max_tasks_per_child: int = 8,
              use_cache: bool = True, progress: Progress | None = None,
              job_fn: Callable | None = None, max_jobs: int | None = MAX_JOBS,
              connect_timeout: float = 30.0, note: Callable[[str], None] | None = None) -> SweepSummary:
    """Run every job of a manifest's sweep and return what became of them.

    Parameters
    ----------
    manifest : Manifest or path
        A validated manifest, or the path of one (validated here).
    out : path
        The sweep folder is ``out/<manifest name>``.
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
    progress : Progress, optional
        Told when the sweep starts and after every job.
    job_fn : callable, optional
        Replaces ``pipeline.run_job`` (same signature; a module-level function). For tests.
    max_jobs : int or None
        Refuse a sweep of more jobs (counted before anything is expanded); None: no limit.
    connect_timeout : float
        Seconds to reach a Dask ``scheduler``.
    note : callable, optional
        ``note(text)`` for messages that are not a job's (folders to redo, stale folders,
        a cluster waiting for workers); default: ``progress.note``, else stderr.

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
    from . import backends

    started = time.perf_counter()
    if note is None:
        note = getattr(progress, "note", None) or _stderr_note
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    manifest = apply_sets(manifest, sets)
    if backend not in ("local", "dask"):
        raise InputError(f"unknown backend {backend!r}: expected local or dask")
    if scheduler and backend != "dask":
        raise InputError("--scheduler needs --backend dask")
    if scheduler:
        backends.check_scheduler_address(scheduler)
    if workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if until is not None:
        from ..pipeline import Stage
        try:
            Stage(until)
        except ValueError:
            raise InputError(f"unknown stage {until!r}: expected one of "
                             f"{', '.join(s.value for s in Stage)}") from None
    check_job_count(manifest, max_jobs)
    jobs, duplicates = plan_jobs(manifest, render=render)
    swept = swept_keys(manifest.sweep)
    sweep_dir = Path(out).expanduser().resolve() / manifest.name
    records = {j.job_id: JobRecord(job_id=j.job_id, object_id=j.object_id, values=j.values,
                                   job_dir=job_dir(sweep_dir, j)) for j in jobs}
    stale: list[Path] = []
    if resume or dry_run:
        for j in jobs:
            path = records[j.job_id].job_dir
            why = check_done(path)
            if why is None:
                records[j.job_id] = replace(records[j.job_id], status=Status.DONE, resumed=True,
                                            seconds=_previous_seconds(path))
            elif path.is_dir() and why != "no done.json":
                note(f"{path.relative_to(sweep_dir)}: {why}: {'would be' if dry_run else 'it is'} redone")
        stale = stale_folders(sweep_dir, jobs)
        if stale:
            shown = ", ".join(str(p.relative_to(sweep_dir)) for p in stale[:10])
            more = f" and {len(stale) - 10} more" if len(stale) > 10 else ""
            note(f"{len(stale)} job folder(s) in {sweep_dir / 'jobs'} are not jobs of this manifest (it was "
                 f"edited since they were made, or --set differs); they are stale and left as they are: "
                 f"{shown}{more}")

    def summary() -> SweepSummary:
        return SweepSummary(name=manifest.name, sweep_dir=sweep_dir, jobs=tuple(records.values()),
                            swept=swept, wall_seconds=time.perf_counter() - started, backend=backend,
                            workers=workers, dry_run=dry_run, duplicates=duplicates, stale=tuple(stale))

    if dry_run:
        return summary()
    todo = [j for j in jobs if records[j.job_id].status != Status.DONE]
    check_folder(sweep_dir, resume, overwrite)
    # A cluster is reached before anything is written: an unreachable one leaves nothing behind.
    cluster = (backends.dask_client(workers, scheduler, connect_timeout=connect_timeout)
               if backend == "dask" and todo else contextlib.nullcontext())
    with stop_on_signals(), cluster as client, sweep_lock(sweep_dir):
        prepare_folder(sweep_dir, resume, overwrite)
        made = not sweep_dir.exists()  # by this run: removed again when it cannot be written
        running = sweep_dir / ".farm" / "running"
        cache_dir = sweep_dir / "cache" if use_cache else None
        csv_path = sweep_dir / "jobs.csv"
        try:
            shutil.rmtree(running, ignore_errors=True)  # markers of an earlier run that was stopped
            running.mkdir(parents=True, exist_ok=True)
            if cache_dir is not None:
                cache_dir.mkdir(exist_ok=True)
                from ..stage_cache import StageCache

                atomic_write(cache_dir / StageCache.POLICY, json.dumps({"private": private_stages(jobs)}) + "\n")
            atomic_write(sweep_dir / "manifest.resolved.yaml", _resolved_yaml(manifest, jobs, sweep_dir, until))
            atomic_write(csv_path, jobs_csv_text(list(records.values()), swept))
        except OSError as exc:
            if made:
                shutil.rmtree(sweep_dir, ignore_errors=True)  # nothing half-made left behind
            raise _os_error(exc, f"the sweep folder {sweep_dir}") from None

        tasks = [backends.Task(spec=j.spec, job_id=j.job_id, object_id=j.object_id,
                               job_dir=str(records[j.job_id].job_dir),
                               cache_dir=str(cache_dir) if cache_dir else None, until=until,
                               running_dir=str(running), job_fn=job_fn) for j in todo]
        # A job whose leader is already done (resume) need not wait for anything.
        # Without a cache there is nothing to wait for.
        waits = {k: v for k, v in leaders(jobs).items() if records[v].status != Status.DONE} if use_cache else {}

        last_write = [time.monotonic()]

        def on_outcome(task, outcome, attempts: int) -> None:
            records[task.job_id] = replace(
                records[task.job_id], status=Status.DONE if outcome.status == "done" else Status.FAILED,
                seconds=float(sum(outcome.seconds.values())), reused=tuple(outcome.reused),
                attempts=attempts, failed_stage=outcome.failed_stage, error=outcome.error)
            if time.monotonic() - last_write[0] > CSV_INTERVAL_S:  # rewriting it per job is quadratic
                atomic_write(csv_path, jobs_csv_text(list(records.values()), swept))
                last_write[0] = time.monotonic()
            if progress is not None:
                progress.update(records[task.job_id])

        if progress is not None:
            progress.start(len(jobs), len(jobs) - len(todo))
        stopped: Interrupted | None = None
        try:
            if tasks and backend == "local":
                backends.run_local(tasks, workers=workers, on_outcome=on_outcome, waits=waits,
                                   max_tasks_per_child=max_tasks_per_child)
            elif tasks:
                backends.run_dask(tasks, workers=workers, scheduler=scheduler, on_outcome=on_outcome,
                                  waits=waits, client=client, note=note)
        except KeyboardInterrupt as exc:  # the workers are gone (the backends saw to it)
            stopped = exc if isinstance(exc, Interrupted) else Interrupted(signal.SIGINT)
        finally:
            if progress is not None:
                progress.close()
            atomic_write(csv_path, jobs_csv_text(list(records.values()), swept))
        if stopped is not None:
            stopped.summary = summary()
            raise stopped
        shutil.rmtree(sweep_dir / ".farm", ignore_errors=True)
    return summary()
