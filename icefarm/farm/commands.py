"""The farm's commands: ``icefarm validate``, ``icefarm sweep`` and ``icefarm bench farm``.

Each click command is a thin shell over a plain function (`validate_manifest`, `run_sweep`,
`bench_farm_run`) so that other code can chain them (sheets and reports after a sweep).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import click

from ..errors import InputError, Interrupted, one_line_each
from ..jobdir import DONE, JOBS_CSV, JOBS_DIR, JobState, error_line, stage_phrase
from .manifest import load_manifest
from .manifest_model import Manifest
from .plan import JobRecord, manifest_warnings
from .points import MAX_JOBS, apply_sets, check_job_count, count_points
from .sweep import SweepOptions, SweepSummary, run_sweep


class BadInput(click.ClickException):
    """An `InputError` on the command line: exit status 2, as the icefarm group gives it."""

    exit_code = 2

    def __init__(self, message: str):
        super().__init__(one_line_each(message))

    def show(self, file=None) -> None:
        click.echo(f"error: {self.format_message()}", err=True)  # as the icefarm group writes it


# --------------------------------------------------------------------------- progress

def _running(total: int, count: int, workers: int | None) -> str:
    """``, 2 running`` while jobs are left (empty when the worker count is unknown)."""
    left = total - count
    return f", {min(workers, left)} running" if workers and left > 0 else ""


def time_left(seconds: float, finished: int, left: int) -> str:
    """``about 3 min left`` from the jobs this run finished so far (empty before the first)."""
    if finished <= 0 or left <= 0:
        return ""
    eta = seconds / finished * left
    text = f"{eta:.0f} s" if eta < 90 else f"{eta / 60:.0f} min" if eta < 5400 else f"{eta / 3600:.1f} h"
    return f"about {text} left"


class LineProgress:
    """One plain line per finished job (logs, CI, anything that is not a terminal), with
    the jobs running and an estimate of the time left."""

    def __init__(self, echo: Callable[[str], None]):
        self.echo = echo
        self.total = self.count = self.failed = self.skipped = 0
        self.workers: int | None = None
        self.started = time.perf_counter()

    def start(self, total: int, already_done: int, workers: int | None = None) -> None:
        self.total, self.count, self.skipped, self.workers = total, already_done, already_done, workers
        self.started = time.perf_counter()
        if already_done:
            self.echo(f"{already_done} of {total} jobs already done (--resume): skipped")

    def update(self, record: JobRecord) -> None:
        self.count += 1
        self.failed += record.status is JobState.FAILED
        values = " ".join(f"{k.split('.')[-1]}={_short(v)}" for k, v in record.values)
        failed = f"FAILED: {error_line(record.error, 'unknown error')}"
        detail = f"{record.seconds:.1f} s" if record.status is JobState.DONE else failed
        reused = f", reused {'+'.join(record.reused)}" if record.reused else ""
        retried = f", attempt {record.attempts}" if record.attempts > 1 else ""
        left = time_left(time.perf_counter() - self.started, self.count - self.skipped, self.total - self.count)
        status = _running(self.total, self.count, self.workers) + (f", {left}" if left else "")
        self.echo(f"[{self.count}/{self.total}{status}] {record.object_id}/{record.job_id} {values} "
                  f"{detail}{reused}{retried}".replace("  ", " "))

    def close(self) -> None:
        pass

    def note(self, text: str) -> None:
        self.echo(f"note: {text}")


class TqdmProgress:
    """A live bar on a terminal: jobs done, failed, and the time left."""

    def __init__(self):
        self.bar = None
        self.failed = 0
        self.workers: int | None = None

    def start(self, total: int, already_done: int, workers: int | None = None) -> None:
        from tqdm import tqdm

        self.workers = workers
        # tqdm's own estimate of the time left counts only the jobs this run finishes
        self.bar = tqdm(total=total, initial=already_done, unit="job", dynamic_ncols=True,
                        desc="sweep", file=sys.stderr)
        self.bar.set_postfix_str(self._postfix())

    def _postfix(self, last: str = "") -> str:
        running = _running(self.bar.total, self.bar.n, self.workers).lstrip(", ")
        return ", ".join(x for x in (running, f"{self.failed} failed", last and f"last {last}") if x)

    def update(self, record: JobRecord) -> None:
        self.failed += record.status is JobState.FAILED
        self.bar.update(1)
        self.bar.set_postfix_str(self._postfix(record.object_id))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def note(self, text: str) -> None:
        from tqdm import tqdm

        tqdm.write(f"note: {text}", file=sys.stderr)


def default_progress():
    """A tqdm bar on stderr when it is a terminal, else plain lines on stdout (with the
    summary; stderr keeps warnings and errors)."""
    if sys.stderr.isatty():
        return TqdmProgress()
    return LineProgress(click.echo)


def _short(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


# --------------------------------------------------------------------------- validate

def validate_manifest(path: str | Path, sets: Sequence[str] = (),
                      max_jobs: int | None = MAX_JOBS) -> tuple[Manifest, str]:
    """Validate ``path`` (and ``--set`` assignments); return the manifest and a short description.

    Raises
    ------
    InputError
        Every problem found, each naming the file, the key path and what was expected; a
        sweep of more than ``max_jobs`` jobs (counted, not expanded).
    """
    manifest = apply_sets(load_manifest(path), sets)
    check_job_count(manifest, max_jobs)
    points = count_points(manifest.sweep)
    n = len(manifest.objects)
    method = manifest.sweep.method.value if manifest.sweep else "none"
    text = (f"{manifest.path}: valid. sweep {manifest.name!r}: {n} object{'s' * (n != 1)} x {points} "
            f"point{'s' * (points != 1)} ({method}) = {n * points} jobs, render: {manifest.render or 'none'}")
    return manifest, text


@click.command("validate")
@click.argument("manifest", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--set", "sets", multiple=True, metavar="GROUP.PARAM=V[,V...]",
              help="Check these overrides too (as `icefarm sweep --set` would apply them).")
@click.option("--max-jobs", type=click.IntRange(min=1), default=MAX_JOBS, show_default=True,
              help="Refuse a sweep of more jobs than this.")
def validate(manifest: Path, sets: tuple[str, ...], max_jobs: int) -> None:
    """Check MANIFEST without running anything.

    Reports every problem at once, each with the file, the key path and what was expected
    (unknown keys come with the nearest valid one; parameter values are checked against
    their domains, see `icefarm params`; mesh and override files must exist).
    Prints the number of jobs the sweep would run, and warns (on stderr) about parameters the
    jobs' storm.mode does not read. Exit status 2 when the manifest is invalid.
    """
    try:
        checked, text = validate_manifest(manifest, sets, max_jobs)
    except InputError as exc:
        raise BadInput(str(exc)) from None
    click.echo(text)
    for line in manifest_warnings(checked):
        click.echo(f"warning: {line}", err=True)


# --------------------------------------------------------------------------- sweep

def format_summary(summary: SweepSummary) -> str:
    """The end-of-sweep report: counts, reuse, failures with their reasons, where things are."""
    ran = sum(r.status is not JobState.PENDING and not r.resumed for r in summary.jobs)
    lines = [f"sweep {summary.name}: {summary.done} done, {summary.failed} failed"
             + (f", {summary.pending} not run" if summary.pending else "")
             + f" of {len(summary.jobs)} jobs"
             + (f" ({summary.resumed} already done)" if summary.resumed else "")
             + f"; {ran} run on {summary.workers} {summary.backend} worker{'s' * (summary.workers != 1)}"
             + f" in {summary.wall_seconds:.1f} s"]
    lines.append(f"stage results reused from the cache: {summary.reused}"
                 + (f"; jobs retried after a worker died: {summary.retried}" if summary.retried else ""))
    if summary.duplicates:
        lines.append(f"{summary.duplicates} sweep point(s) repeated an earlier job and were dropped")
    if summary.stale:
        lines.append(f"{len(summary.stale)} stale job folder(s) of an earlier manifest left in "
                     f"{summary.sweep_dir / JOBS_DIR} (not jobs of this one): "
                     + ", ".join(str(p.relative_to(summary.sweep_dir)) for p in summary.stale[:10])
                     + (" ..." if len(summary.stale) > 10 else ""))
    for r in summary.jobs:
        if r.status is JobState.FAILED:
            stage = f" {stage_phrase(r.failed_stage)}" if r.failed_stage else ""
            lines.append(f"  FAILED {r.object_id}/{r.job_id}{stage}: {error_line(r.error, 'unknown error')}")
    lines.append(f"results: {summary.sweep_dir}  ({JOBS_CSV}, {JOBS_DIR}/<object>/<job>/)")
    return "\n".join(lines)


def format_plan(summary: SweepSummary) -> str:
    """A dry run's job list."""
    lines = [f"dry run: sweep {summary.name} -> {summary.sweep_dir}: {len(summary.jobs)} jobs"
             + (f", {summary.resumed} already done" if summary.resumed else "")
             + (f"; {len(summary.stale)} stale job folder(s) not in this manifest" if summary.stale else "")]
    for r in summary.jobs:
        values = " ".join(f"{k}={_short(v)}" for k, v in r.values)
        state = "done" if r.status is JobState.DONE else "to run"
        lines.append(f"  {r.object_id}/{r.job_id}  {values}  [{state}]")
    return "\n".join(lines)


def make_sweep_command(after: Callable[[SweepSummary], None] | None = None) -> click.Command:
    """The ``sweep`` command; ``after(summary)`` runs when the sweep ends (sheets, report)."""

    @click.command("sweep")
    @click.argument("manifest", type=click.Path(dir_okay=False, path_type=Path))
    @click.option("-o", "--out", type=click.Path(file_okay=False, path_type=Path), default=Path("out"),
                  show_default=True, help="Results go to OUT/<sweep name>/.")
    @click.option("--workers", "-j", type=click.IntRange(min=1), default=lambda: _cores(), show_default="all cores",
                  help="Worker processes; each gets its share of the cores for Dr.Jit/Mitsuba.")
    @click.option("--backend", type=click.Choice(["local", "dask"]), default="local", show_default=True,
                  help="local: a process pool on this machine. dask: a Dask cluster "
                       "(--scheduler ADDRESS, or a LocalCluster of --workers processes).")
    @click.option("--scheduler", metavar="ADDRESS",
                  help="Dask scheduler to use, e.g. tcp://10.0.0.5:8786 (needs --backend dask). "
                       "Workers must import icefarm and see OUT at the same path.")
    @click.option("--set", "sets", multiple=True, metavar="GROUP.PARAM=V[,V...]",
                  help="Override a parameter for every job (one value) or sweep it (a comma list, "
                       "crossed with the manifest's sweep). Repeatable.")
    @click.option("--resume", is_flag=True,
                  help="Continue an existing sweep folder: skip done jobs, redo the others.")
    @click.option("--overwrite", is_flag=True, help="Delete an existing sweep folder and start over.")
    @click.option("--dry-run", is_flag=True, help="List the jobs and stop; nothing is written or run.")
    @click.option("--no-render", is_flag=True, help="Run the stages only, no scene render.")
    @click.option("--until", type=click.Choice(["water", "drips", "trajectories", "surface", "render"]),
                  help="Stop every job after this stage.")
    @click.option("--tasks-per-worker", type=click.IntRange(min=1), default=8, show_default=True,
                  help="Replace a local worker process after this many jobs (bounds memory growth).")
    @click.option("--no-cache", is_flag=True,
                  help="Do not share stage results between jobs (every job computes every stage).")
    @click.option("--max-jobs", type=click.IntRange(min=1), default=MAX_JOBS, show_default=True,
                  help="Refuse a sweep of more jobs than this (counted before anything is expanded).")
    @click.option("--scheduler-timeout", type=click.FloatRange(min=0.1), default=30.0, show_default=True,
                  metavar="SECONDS", help="How long to try reaching the --scheduler before giving up.")
    def sweep(manifest: Path, out: Path, workers: int, backend: str, scheduler: str | None,
              sets: tuple[str, ...], resume: bool, overwrite: bool, dry_run: bool, no_render: bool,
              until: str | None, tasks_per_worker: int, no_cache: bool, max_jobs: int,
              scheduler_timeout: float) -> None:
        """Run every job of MANIFEST's sweep: one job per (object, sweep point).

        Results go to OUT/<name>/: manifest.resolved.yaml, jobs/<object>/<job id>/ (one
        folder per job, done.json written last), jobs.csv and a stage cache shared by the
        jobs, so that a sweep over surface parameters computes water, drips and trajectories
        once per object. A failing job does not stop the others; a job whose worker dies is
        retried once. An existing OUT/<name> needs --resume or --overwrite. Ctrl-C, SIGTERM or
        SIGHUP end the workers and keep the done jobs (--resume finishes the rest). Exit status
        1 when any job failed, 2 for an invalid manifest or option, 128 + the signal when
        stopped by one (130: Ctrl-C, 143: SIGTERM).
        """
        progress = None if dry_run else default_progress()
        try:
            options = SweepOptions(workers=workers, backend=backend, scheduler=scheduler, sets=sets, resume=resume,
                                   overwrite=overwrite, dry_run=dry_run, render=not no_render, until=until,
                                   max_tasks_per_child=tasks_per_worker, use_cache=not no_cache, max_jobs=max_jobs,
                                   connect_timeout=scheduler_timeout)
            summary = run_sweep(manifest, out, options, progress=progress, note=progress.note if progress is not None
                                else lambda text: click.echo(f"note: {text}", err=True))
        except InputError as exc:
            raise BadInput(str(exc)) from None
        except KeyboardInterrupt as exc:
            stop = exc if isinstance(exc, Interrupted) else Interrupted()
            if stop.summary is not None:
                click.echo(format_summary(stop.summary), err=True)
            click.echo(f"interrupted by {stop.name}: the workers were stopped; done jobs are kept, the others "
                       f"have no {DONE}. Finish the sweep with: icefarm sweep {manifest} -o {out} --resume",
                       err=True)
            sys.exit(stop.exit_code)
        except OSError as exc:  # the disk filled up, a folder became read-only, ... while running
            click.echo(one_line_each(f"error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")), err=True)
            sys.exit(1)
        if dry_run:
            click.echo(format_plan(summary))
            return
        click.echo(format_summary(summary))
        if after is not None:
            after(summary)
        if not summary.ok:
            sys.exit(1)

    return sweep


sweep = make_sweep_command()


# --------------------------------------------------------------------------- bench farm

BENCH_MESH = "generator:fountain"


def bench_manifest(jobs: int = 16) -> dict:
    """A stages-only sweep of ``jobs`` independent jobs on a generated fountain.

    The swept parameter is the storm's precipitation (water stage), so no two jobs share a
    stage: the benchmark measures how the farm spreads work, not what the cache saves (it
    runs without one). A coarse voxel keeps each job to a few seconds.
    """
    return {"name": "bench_farm", "seed": 1, "render": None,
            "defaults": {"surface.voxel_size": 0.002},
            "objects": [{"id": "fountain", "mesh": BENCH_MESH, "size_m": 0.4}],
            "sweep": {"method": "grid",
                      "parameters": {"storm.precipitation": {"values": [30.0 + i for i in range(jobs)]}}}}


@dataclass(frozen=True)
class BenchRun:
    """One timed sweep of `bench_farm_run`: its backend and workers, wall and CPU seconds
    (this process and its local workers; a Dask cluster's workers are not counted), and the
    machine's 1-minute load average when it started (others' work too)."""

    backend: str
    workers: int
    jobs: int
    wall: float
    cpu: float
    load: float


def bench_farm_run(jobs: int = 16, workers: Sequence[int] = (1, 2), until: str | None = None,
                   out: Path | None = None, repeat: int = 1, backends: Sequence[str] = ("local",),
                   echo: Callable[[str], None] = lambda s: None) -> list[BenchRun]:
    """Time the same ``jobs``-job sweep (`bench_manifest`) with each backend in ``backends``
    and worker count in ``workers``, taking turns ``repeat`` times (so that a busy spell of
    the machine hits all). ``dask`` starts a LocalCluster of single-threaded worker processes
    for each sweep, as ``icefarm sweep --backend dask`` does; its start-up counts.

    Raises
    ------
    RuntimeError
        A job failed (the timing would mean nothing).
    """
    import os
    import resource

    import yaml

    def cpu() -> float:
        own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime

    runs = []
    with tempfile.TemporaryDirectory(prefix="icefarm-bench-") as tmp:
        root = Path(out) if out is not None else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        path = root / "bench_farm.yaml"
        path.write_text(yaml.safe_dump(bench_manifest(jobs), sort_keys=False))
        for backend, n in [(b, n) for _ in range(repeat) for n in workers for b in backends]:
            load, start, cpu0 = os.getloadavg()[0], time.perf_counter(), cpu()
            # Workers are never recycled here: every run pays the same start-up once per worker.
            options = SweepOptions(workers=n, backend=backend, overwrite=True, render=False, until=until,
                                   max_tasks_per_child=max(jobs, 1), use_cache=False)
            summary = run_sweep(path, root / f"{backend}{n}", options)
            run = BenchRun(backend, n, jobs, time.perf_counter() - start, cpu() - cpu0, load)
            if not summary.ok:
                raise RuntimeError(format_summary(summary))
            runs.append(run)
            echo(f"{backend}, {n} worker{'s' * (n != 1)}: {jobs} jobs in {run.wall:.1f} s wall, {run.cpu:.1f} s CPU "
                 f"here (load average {run.load:.1f} at start)")
    return runs


def bench_farm_report(runs: Sequence[BenchRun]) -> list[str]:
    """What `bench_farm_run`'s runs say, from medians of the wall times: each worker count's
    speed-up over the first (per backend), and each backend's time over the first backend's at
    the same worker count."""
    import statistics

    def key(r: BenchRun) -> tuple[str, int]:
        return r.backend, r.workers

    walls: dict[tuple[str, int], list[float]] = {}
    for r in runs:
        walls.setdefault(key(r), []).append(r.wall)
    median = {k: statistics.median(v) for k, v in walls.items()}
    backends = list(dict.fromkeys(r.backend for r in runs))
    counts = list(dict.fromkeys(r.workers for r in runs))
    jobs = runs[0].jobs if runs else 0
    lines = []
    for b in backends:
        for n in counts[1:]:
            lines.append(f"{b}: speed-up {n} vs {counts[0]} worker{'s' * (counts[0] != 1)}: "
                         f"{median[b, counts[0]] / median[b, n]:.2f}x on {jobs} jobs ({_cores()} cores; medians "
                         f"{median[b, counts[0]]:.1f} s, {median[b, n]:.1f} s)")
    for b in backends[1:]:
        for n in counts:
            over = median[b, n] / median[backends[0], n] - 1.0
            lines.append(f"{b} vs {backends[0]}, {n} worker{'s' * (n != 1)}: {100 * over:+.0f} % wall time (medians "
                         f"{median[b, n]:.1f} s and {median[backends[0], n]:.1f} s of {len(walls[b, n])} runs)")
    return lines


@click.command("farm")
@click.option("--jobs", type=click.IntRange(min=1), default=16, show_default=True,
              help="Jobs in the benchmark sweep.")
@click.option("--workers", "worker_counts", type=click.IntRange(min=1), multiple=True,
              help="Worker counts to compare (repeatable; default 1 and 2).")
@click.option("--backend", "backends", type=click.Choice(["local", "dask"]), multiple=True,
              help="Backends to compare at each worker count (repeatable; default local). `--backend local "
                   "--backend dask` gives the Dask cluster's overhead over the local pool.")
@click.option("--until", type=click.Choice(["water", "drips", "trajectories", "surface"]),
              help="Last stage of each job (default: all stages, no render).")
@click.option("--repeat", type=click.IntRange(min=1), default=1, show_default=True,
              help="Run each backend and worker count this many times, in turns; medians are reported.")
@click.option("-o", "--out", type=click.Path(file_okay=False, path_type=Path),
              help="Keep the benchmark sweeps here (default: a temporary folder).")
def bench_farm(jobs: int, worker_counts: tuple[int, ...], backends: tuple[str, ...], until: str | None,
               repeat: int, out: Path | None) -> None:
    """Farm throughput: the same stages-only sweep on 1 worker, then on 2 (or --workers ...),
    on the local pool (or --backend ...).

    The jobs sweep the rain over a generated fountain, so none reuses another's stages and
    the speed-up is the farm's own (process start-up, scheduling, the spread of the work).
    Prints wall and CPU time of each run, the speed-up over the first worker count, and,
    with two backends, the second's wall time over the first's.
    """
    runs = bench_farm_run(jobs, worker_counts or (1, 2), until, out, repeat, backends or ("local",),
                          echo=click.echo)
    for line in bench_farm_report(runs):
        click.echo(line)
    if max(r.load for r in runs) > 1.0:
        click.echo("note: the machine was busy with other work (load average above 1): the workers "
                   "shared the cores with it, and the speed-up is lower than on an idle machine")


def _cores() -> int:
    from .task import cores

    return cores()
