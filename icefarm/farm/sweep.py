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
import itertools
import json
import math
import os
import shutil
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from .. import params as P
from ..artifacts import atomic_write
from ..errors import InputError
from .manifest import (Axis, Distribution, Manifest, Sweep, SweepMethod, load_manifest,
                       manifest_to_dict)

# The parameter groups each early stage reads: jobs that agree on them share that stage.
WATER_GROUPS = ("water", "proxy")
CSV_INTERVAL_S = 2.0  # jobs.csv is rewritten at most this often while a sweep runs, and at its end


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


# --------------------------------------------------------------------------- sweep points

def split_values(text: str) -> list[str]:
    """Split ``a,b,[1,2,3]`` at the commas outside brackets (Hydra's sweep syntax)."""
    parts, depth, current = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in ")]":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append("".join(current))
            current = []
        else:
            current.append(ch)
    parts.append("".join(current))
    return [p.strip() for p in parts]


def parse_set(text: str) -> tuple[str, tuple]:
    """``"group.param=v1,v2"`` to ``(key, (v1, v2))``, every value validated.

    Raises
    ------
    InputError
        No ``=``, an unknown parameter (with the nearest one), an empty or out-of-domain value.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--set {text!r}: expected group.param=value or group.param=v1,v2,...")
    param = P.lookup(key.strip())
    items = split_values(raw)
    if any(not item for item in items):
        raise InputError(f"--set {text!r}: empty value; give group.param=value or a comma list")
    values = tuple(param.validate(P.parse_value(item)) for item in items)
    if len({repr(v) for v in values}) != len(values):
        raise InputError(f"--set {text!r}: a value is listed twice")
    return param.key, values


def apply_sets(manifest: Manifest, sets: Sequence[str]) -> Manifest:
    """Apply command-line ``--set`` assignments to ``manifest``.

    A single value fixes the parameter for every job (over the defaults, the objects' params
    and the sweep); a comma list sweeps it: it replaces or joins a grid sweep's parameters, and
    is crossed with the points of a zip or random sweep.
    """
    sweep, fixed = manifest.sweep, dict(manifest.fixed)
    for text in sets:
        key, values = parse_set(text)
        if sweep is not None:
            sweep = replace(sweep, axes=tuple(a for a in sweep.axes if a.key != key),
                            product=tuple(a for a in sweep.product if a.key != key))
        if len(values) == 1:
            fixed[key] = values[0]
            continue
        fixed.pop(key, None)
        axis = Axis(key=key, values=values)
        old_axes = [a.key for a in manifest.sweep.axes] if manifest.sweep else []
        if sweep is None:
            sweep = Sweep(method=SweepMethod.GRID, axes=(axis,))
        elif sweep.method is SweepMethod.GRID:
            axes = list(sweep.axes)
            # Keep the manifest's order when the key was already swept there.
            at = old_axes.index(key) if key in old_axes else len(axes)
            axes.insert(min(at, len(axes)), axis)
            sweep = replace(sweep, axes=tuple(axes))
        else:
            sweep = replace(sweep, product=sweep.product + (axis,))
    if sweep is not None and not sweep.axes and not sweep.product:
        sweep = None
    return replace(manifest, sweep=sweep, fixed=fixed)


def swept_keys(sweep: Sweep | None) -> tuple[str, ...]:
    """The swept parameters, in the order jobs.csv lists them."""
    if sweep is None:
        return ()
    return tuple(a.key for a in sweep.axes) + tuple(a.key for a in sweep.product)


def expand(sweep: Sweep | None, seed: int = 0) -> list[dict[str, Any]]:
    """The sweep's points, each ``{"group.name": value}``; ``[{}]`` when there is no sweep.

    Grid: every combination, the last parameter varying fastest. Zip: the i-th value of each
    parameter (one-value lists repeat). Random: ``count`` points drawn with a generator seeded
    by ``seed`` (the same seed gives the same points); lists are drawn from uniformly, ranges by
    their distribution, integers rounded, floats kept to 6 significant digits.
    The command line's crossed parameters (``sweep.product``) multiply these points as a grid.
    """
    if sweep is None:
        return [{}]
    axes = sweep.axes
    if sweep.method is SweepMethod.GRID:
        points = [dict(zip([a.key for a in axes], combo)) for combo in itertools.product(*(a.values for a in axes))]
    elif sweep.method is SweepMethod.ZIP:
        n = max((len(a.values) for a in axes), default=1)
        points = [{a.key: a.values[i if len(a.values) > 1 else 0] for a in axes} for i in range(n)]
    else:
        rng = np.random.default_rng([seed, 0x5EED])
        points = [{a.key: _draw(a, rng) for a in axes} for _ in range(sweep.count or 0)]
    if sweep.product:
        keys = [a.key for a in sweep.product]
        crossed = [dict(zip(keys, combo)) for combo in itertools.product(*(a.values for a in sweep.product))]
        points = [{**p, **c} for p in points for c in crossed]
    return points


def _draw(axis: Axis, rng: np.random.Generator) -> Any:
    param = P.lookup(axis.key)
    if axis.values:
        return axis.values[int(rng.integers(len(axis.values)))]
    lo, hi = axis.low, axis.high
    if axis.distribution is Distribution.LOG_UNIFORM:
        x = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    else:
        x = rng.uniform(lo, hi)
    if param.kind is P.Kind.INT:
        x = int(min(max(round(x), math.ceil(lo)), math.floor(hi)))
    else:
        x = min(max(float(f"{x:.6g}"), lo), hi)
    return param.validate(x)


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
                raise InputError(f"{manifest.path}: object {obj.id}, sweep point {point}: {exc}") from None
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

def job_dir(sweep_dir: Path, job: PlannedJob) -> Path:
    return sweep_dir / "jobs" / job.object_id / job.job_id


def is_done(path: Path) -> bool:
    return (path / "done.json").is_file()


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
        error = (r.error or "").strip().splitlines()
        writer.writerow([r.job_id, r.object_id, *(_format(values.get(k, "")) for k in swept), r.status.value,
                         f"{r.seconds:.3f}", " ".join(r.reused), r.attempts, r.failed_stage or "",
                         error[-1] if error else ""])
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
        data = json.loads((path / "timings.json").read_text())
    except (OSError, ValueError):
        return 0.0
    seconds = data.get("seconds", data) if isinstance(data, Mapping) else {}
    if not isinstance(seconds, Mapping):
        return 0.0
    return float(sum(v for v in seconds.values() if isinstance(v, (int, float)) and not isinstance(v, bool)))


def prepare_folder(sweep_dir: Path, resume: bool, overwrite: bool) -> None:
    """Refuse an existing sweep folder unless resuming; clear it for ``overwrite``."""
    if resume and overwrite:
        raise InputError("--resume and --overwrite exclude each other: resume keeps the done jobs, "
                         "overwrite deletes them")
    if not sweep_dir.exists() or (sweep_dir.is_dir() and not any(sweep_dir.iterdir())):
        return
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
    shutil.rmtree(sweep_dir)


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
    sweep_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(sweep_dir.parent / f".{sweep_dir.name}.lock", "a+") as fh:
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


# --------------------------------------------------------------------------- running

def run_sweep(manifest: Manifest | str | Path, out: str | Path = "out", *, workers: int = 1,
              backend: str = "local", scheduler: str | None = None, sets: Sequence[str] = (),
              resume: bool = False, overwrite: bool = False, dry_run: bool = False,
              render: bool = True, until: str | None = None, max_tasks_per_child: int = 8,
              use_cache: bool = True, progress: Progress | None = None,
              job_fn: Callable | None = None) -> SweepSummary:
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
        half-written ones redone), or delete it. Without either an existing folder is refused.
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

    Returns
    -------
    SweepSummary

    Raises
    ------
    InputError
        An invalid manifest or ``--set``, an existing output folder, an unknown backend.
    """
    from . import backends

    started = time.perf_counter()
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    manifest = apply_sets(manifest, sets)
    if backend not in ("local", "dask"):
        raise InputError(f"unknown backend {backend!r}: expected local or dask")
    if scheduler and backend != "dask":
        raise InputError("--scheduler needs --backend dask")
    if workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if until is not None:
        from ..pipeline import Stage
        try:
            Stage(until)
        except ValueError:
            raise InputError(f"unknown stage {until!r}: expected one of "
                             f"{', '.join(s.value for s in Stage)}") from None
    jobs, duplicates = plan_jobs(manifest, render=render)
    swept = swept_keys(manifest.sweep)
    sweep_dir = Path(out).expanduser().resolve() / manifest.name
    records = {j.job_id: JobRecord(job_id=j.job_id, object_id=j.object_id, values=j.values,
                                   job_dir=job_dir(sweep_dir, j)) for j in jobs}
    for j in jobs:
        path = records[j.job_id].job_dir
        if (resume or dry_run) and is_done(path):
            records[j.job_id] = replace(records[j.job_id], status=Status.DONE, resumed=True,
                                        seconds=_previous_seconds(path))

    def summary() -> SweepSummary:
        return SweepSummary(name=manifest.name, sweep_dir=sweep_dir, jobs=tuple(records.values()),
                            swept=swept, wall_seconds=time.perf_counter() - started, backend=backend,
                            workers=workers, dry_run=dry_run, duplicates=duplicates)

    if dry_run:
        return summary()
    with sweep_lock(sweep_dir):
        prepare_folder(sweep_dir, resume, overwrite)
        running = sweep_dir / ".farm" / "running"
        shutil.rmtree(running, ignore_errors=True)  # markers of an earlier run that was stopped
        running.mkdir(parents=True, exist_ok=True)
        cache_dir = sweep_dir / "cache" if use_cache else None
        if cache_dir is not None:
            cache_dir.mkdir(exist_ok=True)
        atomic_write(sweep_dir / "manifest.resolved.yaml", _resolved_yaml(manifest, jobs, sweep_dir, until))
        csv_path = sweep_dir / "jobs.csv"
        atomic_write(csv_path, jobs_csv_text(list(records.values()), swept))

        todo = [j for j in jobs if records[j.job_id].status != Status.DONE]
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
        try:
            if tasks and backend == "local":
                backends.run_local(tasks, workers=workers, on_outcome=on_outcome, waits=waits,
                                   max_tasks_per_child=max_tasks_per_child)
            elif tasks:
                backends.run_dask(tasks, workers=workers, scheduler=scheduler, on_outcome=on_outcome,
                                  waits=waits)
        finally:
            if progress is not None:
                progress.close()
            atomic_write(csv_path, jobs_csv_text(list(records.values()), swept))
        shutil.rmtree(sweep_dir / ".farm", ignore_errors=True)
    return summary()
