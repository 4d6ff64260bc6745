"""Benchmark drivers behind `icefarm bench`: medians over repeated runs."""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .geometry import ray_caster
from .mesh import prepare
from .stages.drips import find_drips
from .stages.trajectories import grow_trajectories
from .stages.water import compute_water


@dataclass(frozen=True)
class StageRuns:
    faces: int
    icicles: int
    ice_faces: int  # of the last run
    seconds: dict  # stage -> list of seconds, one per run
    ice_faces_runs: tuple = ()  # ice faces of each run (surface timed only)


def stage_timings(mesh_path: str | Path | trimesh.Trimesh, size_m: float, p: dict, repeat: int,
                  surface: bool = False, on_run: Callable[[], None] | None = None,
                  exclude: tuple = ()) -> StageRuns:
    """Time stages 1-3 (and 4) ``repeat`` times on a fresh copy of the mesh each run.

    ``mesh_path`` is a mesh file or a mesh already in memory (see `icefarm.mesh.prepare`).
    Mesh loading is excluded; everything else counts, the ray-tracing BVH included
    (built in stage 1 and shared by stages 2-3, as in the pipeline). ``on_run`` is
    called after each run (a progress bar's tick); ``exclude`` holds boxes ``((lo), (hi))``
    in meters, in the prepared mesh's frame, where no icicle may hang (as a job's ``exclude``).
    """
    prepared = prepare(mesh_path, size_m, p["water"]["gravity"])
    g = np.asarray(p["water"]["gravity"], dtype=np.float64)
    g /= np.linalg.norm(g)
    names = ["water", "drips", "trajectories"] + (["surface"] if surface else [])
    seconds: dict[str, list[float]] = {name: [] for name in names}
    icicles = ice_faces = 0
    ice_faces_runs: list[int] = []
    for run in range(repeat):
        mesh = prepared.mesh.copy()  # no cached normals, edges or BVH: the stages pay for them
        rng = np.random.default_rng(run)
        t0 = time.perf_counter()
        caster = ray_caster(mesh)
        water = compute_water(mesh, g, p["water"]["rays"], p["water"]["influence_radius"], rng, caster=caster,
                              pools=p["water"]["pools"])
        t1 = time.perf_counter()
        drips = find_drips(mesh, water.water, g, p["drips"]["count"], p["drips"]["drip_limit"], rng,
                           exclude_boxes=exclude, caster=caster)
        t2 = time.perf_counter()
        traj = grow_trajectories(mesh, drips.positions, mesh.face_normals[drips.faces], drips.water, g, rng,
                                 drip_limit=p["drips"]["drip_limit"], caster=caster, **p["trajectories"])
        t3 = time.perf_counter()
        for name, dt in zip(names, (t1 - t0, t2 - t1, t3 - t2)):
            seconds[name].append(dt)
        icicles = len(drips.positions)
        if surface:
            from .stages.surface import build_ice

            t4 = time.perf_counter()
            ice = build_ice(mesh, mesh, water, drips, traj, p["surface"], p["glaze"], g, rng, measure=False)
            seconds["surface"].append(time.perf_counter() - t4)
            ice_faces = len(ice.faces)
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
    from .pipeline import GENERATOR_PREFIX, JobSpec, run_job
    from .scene.config import load_render_config
    from .scene.render import render_job

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
            if outcome.status != "done":
                raise RuntimeError(f"benchmark job failed in stage {outcome.failed_stage}: {outcome.error}")
            stats = json.loads((job_dir / "timings.json").read_text())
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
                      povray_cpu=column("povray_write_cpu_seconds"))


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


def growth_timings(mesh: str, size_m: float, p: dict, render_config: str | None, frames: int,
                   seed: int = 0) -> GrowthRuns:
    """Run one job with ``frames`` growth frames in a scratch folder and time its frames
    against the job's own stage 4 and render (``p`` is `icefarm.params.resolve` output)."""
    from .growth import read_frames
    from .pipeline import GENERATOR_PREFIX, JobSpec, run_job

    if not mesh.startswith(GENERATOR_PREFIX):
        mesh = str(Path(mesh).resolve())
    p = {**p, "growth": {**p["growth"], "frames": frames}}
    spec = JobSpec(object_id=Path(mesh).stem, mesh=mesh, size_m=size_m, params=p, seed=seed, render=render_config)
    with tempfile.TemporaryDirectory(prefix="icefarm-bench-") as tmp:
        outcome = run_job(spec, Path(tmp))
        if outcome.status != "done":
            raise RuntimeError(f"benchmark job failed in stage {outcome.failed_stage}: {outcome.error}")
        rows = read_frames(Path(tmp) / "growth")
        stats = json.loads((Path(tmp) / "timings.json").read_text())
    return GrowthRuns(ice_faces=int(stats.get("ice_faces", 0)), surface=outcome.seconds["surface"],
                      render=outcome.seconds.get("render", 0.0),
                      frame_surface=tuple(r["surface_seconds"] for r in rows),
                      frame_render=tuple(r["render_seconds"] for r in rows), growth=outcome.seconds["growth"])
