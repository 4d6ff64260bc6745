"""Benchmark drivers behind `icefarm bench`: medians over repeated runs."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import trimesh

from ..job import Stage, Step, run_stages
from ..jobdir import JobState, read_job
from ..mesh import prepare
from ..params import Params


@dataclass(frozen=True)
class StageRuns:
    faces: int
    icicles: int
    ice_faces: int  # of the last run
    seconds: dict  # step -> list of seconds, one per run
    ice_faces_runs: tuple = ()  # ice faces of each run (surface timed only)


def stage_timings(mesh_path: str | Path | trimesh.Trimesh, size_m: float, p: Params, repeat: int,
                  surface: bool = False, on_run: Callable[[], None] | None = None, **job: Any) -> StageRuns:
    """Time the stages as a job runs them (`icefarm.job.run_stages`), ``repeat`` times.

    Each run starts from a fresh copy of the prepared mesh (no cached normals, edges or
    BVH: the stages pay for them) and uses seed ``run``. Mesh loading is excluded;
    everything else counts, the ray-tracing BVH included (built in stage 1 and shared by
    stages 2-3, as in a job), and so do the proxy of a problem mesh and the ground ice
    when the parameters ask for them. ``mesh_path`` is a mesh file or a mesh already in
    memory (see `icefarm.mesh.prepare`); ``on_run`` is called after each run (a progress
    bar's tick); ``job`` holds a job's other inputs (`icefarm.job.JobInputs`: ``exclude``,
    ``placement``).
    """
    prepared = prepare(mesh_path, size_m, p.water.gravity)
    seconds: dict[str, list[float]] = {}
    icicles = ice_faces = 0
    ice_faces_runs: list[int] = []
    for run in range(repeat):
        def timed(step: Step, key: str | None, work: Callable[[], Any]) -> Any:
            start = time.perf_counter()
            value = work()
            seconds.setdefault(step.name, []).append(time.perf_counter() - start)
            return value

        fresh = dataclasses.replace(prepared, mesh=prepared.mesh.copy())
        result = run_stages(fresh, p, run, until=None if surface else Stage.TRAJECTORIES, step=timed, **job)
        icicles = len(result.drips.positions)
        if surface:
            ice_faces = len(result.ice.faces)
            ice_faces_runs.append(ice_faces)
        if on_run is not None:
            on_run()
    return StageRuns(len(prepared.mesh.faces), icicles, ice_faces, seconds, tuple(ice_faces_runs))


@dataclass(frozen=True)
class RenderRuns:
    """Per-run seconds of a job's render step (`render_timings`).

    Attributes
    ----------
    ice_faces : int
    variant : str
        Mitsuba variant that rendered.
    step : tuple of float
        Wall time of the job's whole render step: writing both scenes, loading, rendering,
        writing the images.
    render : tuple of float
        Mitsuba's render time inside the job (the POV-Ray files are written meanwhile).
    alone : tuple of float
        Mitsuba's render time when the job's scene is rendered again with nothing else
        running: the reference the overhead is measured against.
    write, load, wait : tuple of float
        The job's scene overhead: writing before the render, loading scene.xml, waiting
        for the POV-Ray files after the render.
    povray_cpu : tuple of float
        CPU time of the POV-Ray writer, which runs during the render.
    views : tuple of tuple of float
        Per run, Mitsuba's seconds per view (rendering and denoising).
    denoise : tuple of float
        Per run, the denoiser's seconds, all views.
    """

    ice_faces: int
    variant: str
    step: tuple
    render: tuple
    alone: tuple
    write: tuple
    load: tuple
    wait: tuple
    povray_cpu: tuple
    views: tuple = ()
    denoise: tuple = ()

    @property
    def scene(self) -> tuple:
        """Per run: writing, loading and waiting for the scenes."""
        return tuple(w + lo + wa for w, lo, wa in zip(self.write, self.load, self.wait))


def render_timings(mesh: str, size_m: float, p: dict, render_config: str, repeat: int,
                   seed: int = 0, on_run: Callable[[], None] | None = None) -> RenderRuns:
    """Time the render step of a real job ``repeat`` times, as a sweep worker runs it.

    A first job fills a stage cache and Dr.Jit's kernel cache (a worker's first job pays
    for both once); each timed job then runs in a fresh folder with stages 1-4 from the
    cache, so only scene writing, loading and rendering differ between runs. Each job's
    scene is then rendered once more on its own, for the render time without overhead.

    Parameters
    ----------
    mesh : str
        Mesh path or ``generator:NAME``.
    render_config : str
        Render config name or YAML path.
    """
    from ..job.pipeline import GENERATOR_PREFIX, JobSpec, run_job
    from ..scene.config import load_render_config
    from ..scene.render import render_job

    if not mesh.startswith(GENERATOR_PREFIX):
        mesh = str(Path(mesh).resolve())
    spec = JobSpec(object_id=Path(mesh).stem, mesh=mesh, size_m=size_m, params=p, seed=seed,
                   render=render_config)
    config = load_render_config(render_config)
    runs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="icefarm-bench-") as tmp:
        for run in range(repeat + 1):
            job_dir = Path(tmp) / f"job{run}"
            outcome = run_job(spec, job_dir, Path(tmp) / "cache")
            if outcome.status is not JobState.DONE:
                raise RuntimeError(f"benchmark job failed in stage {outcome.failed_stage}: {outcome.error}")
            stats = read_job(job_dir).stats
            if run > 0:
                alone = render_job(job_dir, config)
                runs.append({**stats, "step": outcome.seconds["render"], "alone": alone.seconds})
            shutil.rmtree(job_dir)
            if on_run is not None:
                on_run()
    column = lambda key: tuple(float(r[key]) for r in runs)  # noqa: E731
    return RenderRuns(ice_faces=int(runs[-1].get("ice_faces", 0)), variant=str(runs[-1]["render_variant"]),
                      step=column("step"), render=column("render_seconds"), alone=column("alone"),
                      write=column("scene_write_seconds"),
                      load=column("scene_load_seconds"), wait=column("scene_wait_seconds"),
                      povray_cpu=column("povray_write_cpu_seconds"),
                      views=tuple(tuple(r.get("render_view_seconds", ())) for r in runs),
                      denoise=tuple(float(r.get("denoise_seconds", 0.0)) for r in runs))


@dataclass(frozen=True)
class JobRuns:
    """Seconds of whole jobs (`job_timings`), one entry per run.

    Attributes
    ----------
    ice_faces : int
        Of the last run.
    steps : dict
        Step name (``timings.json``'s ``seconds``: prepare, water, ..., measure, render,
        usd) to its seconds, one per run.
    total : tuple of float
        Each job's wall-clock seconds, all steps and the writing between them.
    usd_write : tuple of float
        Each job's USD export, written in the render's writer thread while Mitsuba renders
        (its ``usd`` step is what was left to wait for after the render); empty without a render.
    measure_beside : tuple of float
        Each job's measures, taken in a thread of their own while it rendered (its ``measure``
        step is the wait after the render); empty without a render.
    """

    ice_faces: int
    steps: dict
    total: tuple
    usd_write: tuple = ()
    measure_beside: tuple = ()


def job_timings(mesh: str, size_m: float | None, p: Params, render_config: str | None, repeat: int,
                seed: int = 0, on_run: Callable[[], None] | None = None) -> JobRuns:
    """Run a whole job ``repeat`` times in scratch folders, without a stage cache, as
    ``icefarm run`` does (``size_m`` None: the size a real-size generator or a USD file
    carries; ``render_config`` None: no render)."""
    from ..job.pipeline import GENERATOR_PREFIX, JobSpec, run_job

    if not mesh.startswith(GENERATOR_PREFIX):
        mesh = str(Path(mesh).resolve())
    spec = JobSpec(object_id=Path(mesh).stem, mesh=mesh, size_m=size_m, params=p, seed=seed, render=render_config)
    steps: dict[str, list[float]] = {}
    total, usd_write, measure_beside, faces = [], [], [], 0
    with tempfile.TemporaryDirectory(prefix="icefarm-bench-") as tmp:
        for run in range(repeat):
            job_dir = Path(tmp) / f"job{run}"
            start = time.perf_counter()
            outcome = run_job(spec, job_dir)
            total.append(time.perf_counter() - start)
            if outcome.status is not JobState.DONE:
                raise RuntimeError(f"benchmark job failed in stage {outcome.failed_stage}: {outcome.error}")
            for step, seconds in outcome.seconds.items():
                steps.setdefault(step, []).append(float(seconds))
            stats = read_job(job_dir).stats
            faces = int(stats.get("ice_faces", 0))
            if "usd_write_seconds" in stats:
                usd_write.append(float(stats["usd_write_seconds"]))
            if "measure_beside_seconds" in stats:
                measure_beside.append(float(stats["measure_beside_seconds"]))
            shutil.rmtree(job_dir)
            if on_run is not None:
                on_run()
    return JobRuns(ice_faces=faces, steps={k: tuple(v) for k, v in steps.items()}, total=tuple(total),
                   usd_write=tuple(usd_write), measure_beside=tuple(measure_beside))


def peak_memory_gb() -> float:
    """Peak resident memory of this process so far, GB (Linux reports KiB, macOS bytes)."""
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**30 if sys.platform == "darwin" else peak / 2**20


@dataclass(frozen=True)
class GrowthRuns:
    """Seconds of a job with growth frames (`growth_timings`).

    Attributes
    ----------
    ice_faces : int
        Of the full growth.
    surface, render : float
        The job's own stage 4 and render step, seconds.
    frame_surface, frame_render : tuple of float
        Each frame's stage 4 (with writing its PLY) and render (scene, load, render, PNG).
    growth : float
        The whole growth step: frames, movie, USD, measures.
    """

    ice_faces: int
    surface: float
    render: float
    frame_surface: tuple
    frame_render: tuple
    growth: float


def growth_timings(mesh: str, size_m: float, p: Params, render_config: str | None, frames: int,
                   seed: int = 0) -> GrowthRuns:
    """Run one job with ``frames`` growth frames in a scratch folder and time its frames
    against the job's own stage 4 and render (``p``: the resolved parameters)."""
    from ..job.frames import read_frames
    from ..job.pipeline import GENERATOR_PREFIX, JobSpec, run_job

    if not mesh.startswith(GENERATOR_PREFIX):
        mesh = str(Path(mesh).resolve())
    p = p.updated({"growth.frames": frames})
    spec = JobSpec(object_id=Path(mesh).stem, mesh=mesh, size_m=size_m, params=p, seed=seed, render=render_config)
    with tempfile.TemporaryDirectory(prefix="icefarm-bench-") as tmp:
        outcome = run_job(spec, Path(tmp))
        if outcome.status is not JobState.DONE:
            raise RuntimeError(f"benchmark job failed in stage {outcome.failed_stage}: {outcome.error}")
        rows = read_frames(Path(tmp) / "growth")
        stats = read_job(Path(tmp)).stats
    return GrowthRuns(ice_faces=int(stats.get("ice_faces", 0)), surface=outcome.seconds["surface"],
                      render=outcome.seconds.get("render", 0.0),
                      frame_surface=tuple(r["surface_seconds"] for r in rows),
                      frame_render=tuple(r["render_seconds"] for r in rows), growth=outcome.seconds["growth"])
