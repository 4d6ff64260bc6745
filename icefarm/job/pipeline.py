"""Run one job: prepare the mesh, the four stages, the scene and the render.

Every stage result is cached under a key made from the hashes of its inputs and of the
parameters it reads, so a sweep over surface parameters reuses stages 1-3 and one over
trajectory parameters reuses stages 1-2. Artifacts follow the job-folder contract (`icefarm.jobdir`);
``done.json`` comes last and atomically, ``error.json`` names the failed stage.
"""

from __future__ import annotations

import contextlib
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import trimesh

from .. import artifacts
from ..artifacts import read_ice_mesh, trajectories_from_json
from ..asset_io import USD_SUFFIXES
from ..errors import InputError, cannot_write
from ..generators import GENERATOR_PREFIX
from ..jobdir import (
    DONE,
    ERROR,
    GROWTH_DIR,
    ICE,
    OBJECT_USDC,
    PARAMS,
    SCENE_USDA,
    TIMINGS,
    TRAJECTORIES,
    JobState,
    clear_job,
    job_state,
)
from ..mesh import PreparedMesh, prepare
from ..params import Params
from ..progress import ProgressMode, StepProgress, step_progress
from ..scene.material import Material
from . import (
    JobInputs,
    Stage,
    StageResults,
    Step,
    beside_render,
    build_surface,
    ice_mesh,
    run_graph,
    run_step,
    stage_rng,
    stops,
)
from .cache import StageCache, digest as _digest, file_digest as _file_digest
from .render import render_step
from .stats import JobStats, write_record


class Box(NamedTuple):
    """An axis-aligned box where no icicle may hang (a manifest's ``exclude``, ``--exclude``):
    its lowest and highest corners, in meters, in the prepared object's frame. A pair, so
    ``lo, hi = box`` and plain ``((lo), (hi))`` pairs work alike."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


@dataclass(frozen=True)
class JobSpec:
    """Everything that defines one job; its hash is the job id.

    ``mesh`` is an absolute path or ``generator:NAME``; ``params`` are resolved
    (`icefarm.params.resolve`); ``exclude`` holds `Box` es (meters, the object's
    frame) where no icicle hangs; ``overrides`` pairs a stage name with a file that
    replaces its result; ``render`` is a render config name or path, None for no render;
    ``material`` the object's (None: the default); ``placement`` is ``ground`` (the object
    stands on the ground plane) or ``hanging``.
    """

    object_id: str
    mesh: str
    size_m: float | None  # None: the size the mesh carries (USD, glTF, a real-size generator)
    params: Params
    seed: int = 0
    render: str | None = None
    exclude: tuple[Box, ...] = ()
    overrides: tuple = ()
    material: Material | None = None
    placement: str = "ground"


@dataclass(frozen=True)
class JobOutcome:
    status: JobState
    seconds: dict = field(default_factory=dict)
    reused: tuple = ()
    failed_stage: str | None = None
    error: str | None = None


def mesh_digest(mesh: str) -> str:
    """Content hash of a mesh file (or of a generator's name)."""
    return _digest(mesh) if mesh.startswith(GENERATOR_PREFIX) else _file_digest(mesh)


def render_digest(render: str | None) -> str:
    """Hash of the resolved render config, so editing a config file changes job ids."""
    if render is None:
        return "none"
    from ..scene.config import load_render_config, render_config_to_dict

    return _digest(render_config_to_dict(load_render_config(render)))


def job_id(spec: JobSpec) -> str:
    """Short stable hash of mesh content, size, params, render config, seed and extras."""
    return _digest(
        mesh_digest(spec.mesh), spec.size_m, spec.params, render_digest(spec.render), spec.seed,
        spec.exclude, [(stage, _file_digest(path)) for stage, path in spec.overrides],
        spec.material.to_dict() if spec.material else (),
        spec.placement,
    )[:12]


def load_object(spec: JobSpec) -> PreparedMesh:
    """The job's mesh, cleaned and in meters (without ``size_m``: at the size it carries)."""
    gravity = spec.params.water.gravity
    if spec.mesh.startswith(GENERATOR_PREFIX):
        from ..generators import generate, natural_size

        name = spec.mesh[len(GENERATOR_PREFIX):]
        size = spec.size_m if spec.size_m is not None else natural_size(name)
        if size is None:
            raise InputError(f"{spec.mesh} is in arbitrary units: give its real height in meters (size_m)")
        return prepare(generate(name), size, gravity)
    return prepare(spec.mesh, spec.size_m, gravity)


def _load_source(spec: JobSpec, prepared: PreparedMesh) -> trimesh.Trimesh | None:
    """The rain source surface, in the object's frame (same scale and offset)."""
    source = spec.params.water.source
    if source == "auto":
        return None
    path = Path(source)
    if not path.is_absolute() and not spec.mesh.startswith(GENERATOR_PREFIX):
        path = Path(spec.mesh).parent / path
    mesh = trimesh.load(path, force="mesh", process=False) if path.is_file() else None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"water.source {source!r}: no mesh found at {path}")
    return trimesh.Trimesh(mesh.vertices * prepared.scale - prepared.offset, mesh.faces, process=False)


@dataclass
class _Run:
    """The bookkeeping of one job in progress: which stage, how long each took, whether
    long work shows progress bars (a job run on its own, not inside a sweep's workers)."""

    stage: str = "prepare"
    seconds: dict = field(default_factory=dict)
    progress: bool = False
    steps: StepProgress = field(default_factory=lambda: step_progress(ProgressMode.OFF))

    def timed(self, stage: str, work: Callable[[], Any], own_bars: bool = False) -> Any:
        """Run and time step ``stage``; ``own_bars``: the work draws its own progress bars
        (the render's samples, the growth frames), so no step line is drawn over them."""
        self.stage = stage
        start = time.perf_counter()
        with (contextlib.nullcontext() if own_bars and self.progress else self.steps.step(stage)):
            value = work()
        self.seconds[stage] = round(time.perf_counter() - start, 6)
        # What fails before the next step starts (glue, imports, a config read) is not this
        # step's fault: error.json says "after <step>", not "<step>".
        self.stage = f"after {stage}"
        return value


def run_job(spec: JobSpec, job_dir: Path, cache_dir: Path | None = None,
            until: Stage | None = None, progress: bool | ProgressMode = False,
            defer_render: bool = False, measure_beside: bool = True) -> JobOutcome:
    """Run one job into ``job_dir``; never raises for a failure of the job itself.

    What an earlier job wrote in ``job_dir`` is removed first (`icefarm.jobdir.clear_job`;
    other files stay). A failure writes ``error.json`` (stage, message, traceback) and returns
    status ``failed``; success writes ``done.json`` last. ``until`` stops after that stage;
    ``progress`` shows what the job is doing on stderr (`icefarm.progress`): ``BAR`` (or
    True) a live line per step and bars over a render's samples and growth frames,
    ``LINES`` a plain line as each step starts and ends, ``OFF`` (or False) nothing.
    ``defer_render`` stops a whole job with a render (and no growth frames) before its render:
    its files and ``timings.json`` are written, no ``done.json``, and the status is
    ``pending`` until `finish_render` renders it (on another machine of a farm).
    ``measure_beside`` takes the measures while Mitsuba renders (`graph.beside_render`), for a
    job with a core to spare beside the render's; a farm worker whose share is one core
    measures first, as the render would only wait for the core.

    Raises
    ------
    InputError
        ``job_dir`` cannot take the job's records (a full disk, a folder made read-only):
        one line, where writing ``error.json`` in the handler had added a second traceback.
    """
    job_dir = Path(job_dir)
    try:
        job_dir.mkdir(parents=True, exist_ok=True)
        # A folder reused for a new job: its done.json must vouch for this job's files only
        clear_job(job_dir)
    except OSError as exc:
        raise cannot_write(exc, f"the job folder {job_dir}") from None
    mode = progress if isinstance(progress, ProgressMode) else (ProgressMode.BAR if progress else ProgressMode.OFF)
    run = _Run(progress=mode is ProgressMode.BAR, steps=step_progress(mode))
    cache = StageCache(Path(cache_dir) if cache_dir else None)
    defer = defer_render and renders_apart(spec, until)
    try:
        figures = _run_stages(spec, job_dir, run, cache, until, defer, measure_beside)
    except Exception as exc:
        return _failed(job_dir, run, exc, tuple(cache.reused))
    stats = JobStats(run.seconds, figures, tuple(cache.reused), tuple(cache.warnings), render_pending=defer)
    if defer:
        stats.write(job_dir / TIMINGS)
        return JobOutcome(JobState.PENDING, dict(run.seconds), stats.reused)
    return _finished(spec, job_dir, stats)


def renders_apart(spec: JobSpec, until: Stage | None = None) -> bool:
    """Whether ``spec``'s render can run apart from its stages (`finish_render`): a whole job
    with a render config and no growth frames (those render inside the surface stage's loop)."""
    return spec.render is not None and until is None and not spec.params.growth.frames


def finish_render(spec: JobSpec, job_dir: Path, progress: bool = False) -> JobOutcome:
    """Render a job whose stages `run_job` ran with ``defer_render`` (its ``ice.ply``,
    ``trajectories.json`` and ``timings.json`` in ``job_dir``) and finish it: its render
    figures join ``timings.json`` and ``done.json`` is written last. Never raises for a
    failure of the job itself (``error.json``, status ``failed``, stage ``render``).

    Raises
    ------
    InputError
        ``job_dir`` holds no job waiting for its render (never run, finished, or failed):
        nothing there is touched.
    """
    job_dir = Path(job_dir)
    geometry = JobStats.read(job_dir / TIMINGS)
    if not geometry.render_pending or job_state(job_dir) is not JobState.PENDING:
        raise InputError(f"{job_dir} holds no job waiting for its render: run it with run_job(defer_render=True)")
    run = _Run(progress=progress)
    run.seconds = dict(geometry.seconds)
    try:
        run.stage = "render"
        prepared = load_object(spec)
        ice = read_ice_mesh(job_dir / ICE)
        axes = trajectories_from_json(job_dir / TRAJECTORIES).points
        stats = render_step(spec, job_dir, prepared.mesh, ice if isinstance(ice, trimesh.Trimesh) else None,
                            axes, run.timed, run.progress)
    except Exception as exc:
        return _failed(job_dir, run, exc, geometry.reused)
    return _finished(spec, job_dir, replace(geometry.adding(stats), seconds=run.seconds, render_pending=False))


def _failed(job_dir: Path, run: _Run, exc: Exception, reused: tuple) -> JobOutcome:
    """error.json for a job that failed in ``run.stage``, and its outcome."""
    message = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
    write_record(job_dir / ERROR, {
        "stage": run.stage, "message": message, "traceback": traceback.format_exc(),
        "seconds": run.seconds,
    })
    return JobOutcome(JobState.FAILED, dict(run.seconds), reused, run.stage, message)


def _finished(spec: JobSpec, job_dir: Path, stats: JobStats) -> JobOutcome:
    """timings.json, then done.json: a finished job's records."""
    stats.write(job_dir / TIMINGS)
    # Last, and listing every artifact with its size and digest: `--resume` checks them.
    write_record(job_dir / DONE, {"job": spec.object_id, **stats.as_json(),
                                  "artifacts": artifacts.list_artifacts(job_dir)})
    return JobOutcome(JobState.DONE, dict(stats.seconds), stats.reused)


def meshing_params(spec: JobSpec) -> tuple[Params, dict]:
    """The parameters stage 4 meshes with, for how the job will be seen, and the figures
    that record it: a render config that shows less than lookdev's (smaller, or without an
    ice view) scales ``surface.face_budget`` and ``surface.error_px`` to its view
    (`icefarm.stages.surface.detail.view_surface`); a job without a render meshes for lookdev.
    ``params.yaml`` keeps the values as set."""
    from ..stages.surface import VIEW_PX, meshing_view, view_surface

    p = spec.params
    view = meshing_view(None)
    if spec.render is not None:
        from ..scene.config import load_render_config

        config = load_render_config(spec.render)
        view = meshing_view(config.resolution, any(v.frame == "ice" for v in config.views))
    surface = view_surface(p.surface, view)
    stats = {"mesh_view_px": [view.width, view.height], "mesh_ice_view": view.ice_view,
             "mesh_face_budget": surface.face_budget,
             "mesh_error_px": round(surface.error_px * view.width / VIEW_PX, 6)}
    return replace(p, surface=surface), stats


def _run_stages(spec: JobSpec, job_dir: Path, run: _Run, cache: StageCache, until: Stage | None,
                defer_render: bool = False, measure_beside: bool = True) -> dict:
    artifacts.write_yaml(job_dir / PARAMS, spec.params.as_dict())
    run.stage = "render config"  # read first: a bad one fails the job before its stages compute anything
    p, meshed = meshing_params(spec)
    prepared = run.timed("prepare", lambda: load_object(spec))
    stats: dict[str, Any] = {"input_faces": prepared.problems.faces, "problems": vars(prepared.problems),
                             "placement": spec.placement, **meshed}
    inputs = JobInputs(prepared, p, spec.seed, placement=spec.placement, exclude=spec.exclude,
                       overrides=dict(spec.overrides), source=lambda: _load_source(spec, prepared),
                       mesh_key=_digest(mesh_digest(spec.mesh), spec.size_m, p.water.gravity), note=run.steps.note)

    def step(s: Step, key: str | None, work: Callable[[], Any]) -> Any:
        return run.timed(s.name, (lambda: cache.get(s.name, key, work)) if key else work)

    def on_step(s: Step, results: StageResults) -> None:
        """Each step's file and figures, as soon as it is there."""
        if s.write is not None:
            s.write(job_dir, results)
        if s.figures is not None:
            stats.update(s.figures(inputs, results))

    rendering = spec.render is not None and not stops(until, Stage.SURFACE) and not defer_render
    beside = beside_render(inputs) if rendering and measure_beside else ()
    r = run_graph(inputs, until=until, step=step, on_step=on_step, measuring=True, skip={s.name for s in beside})
    if r.ice is None:
        return stats
    if rendering:
        assert r.trajectories is not None
        with ThreadPoolExecutor(1) as pool:
            later = [(s, pool.submit(_timed_apart, s, inputs, r)) for s in beside]
            stats.update(render_step(spec, job_dir, r.mesh, ice_mesh(r), r.trajectories.points, run.timed,
                                     run.progress))
            for s, future in later:  # the step's own time is the wait; a failure fails it there
                value, seconds = run.timed(s.name, future.result)
                r = replace(r, **{s.field: value})
                on_step(s, r)
                stats[f"{s.name}_beside_seconds"] = round(seconds, 3)
    if Path(spec.mesh).suffix.lower() in USD_SUFFIXES:  # rendered or not: the ice over the asset's file
        from ..export.ice_layer import write_ice_layer

        try:
            run.timed("ice_layer", lambda: write_ice_layer(job_dir, spec.mesh, scale=prepared.scale,
                                                           offset=prepared.offset, impurity=p.surface.impurity))
        except InputError as exc:  # an asset icefarm reads but USD cannot open: the job stands
            stats["ice_layer_skipped"] = str(exc)
    if p.growth.frames and until is None:  # growth/: stages 1-3 as they are, stage 4 per frame
        stats.update(run.timed("growth", lambda: _growth(spec, job_dir, run, inputs, r), own_bars=True))
    return stats


def _timed_apart(s: Step, inputs: JobInputs, r: StageResults) -> tuple[Any, float]:
    """Step ``s`` run bare in a thread of its own, and its wall seconds there."""
    start = time.perf_counter()
    return run_step(s, inputs, r), time.perf_counter() - start


def _growth(spec: JobSpec, job_dir: Path, run: _Run, inputs: JobInputs, r: StageResults) -> dict:
    """``growth/``: the ice at ``growth.frames`` moments of its growth (`icefarm.job.frames`),
    rendered with the job's camera: the one framed on the full-grown ice."""
    from .frames import FrameView, Growing, grow_frames

    p, gravity = inputs.params, inputs.gravity
    assert r.drips is not None and r.trajectories is not None  # the graph reached stage 4
    view = None
    if spec.render is not None:
        from ..scene.config import load_render_config
        from ..scene.write import job_scene

        full = trimesh.load(job_dir / ICE, process=False, force="mesh")
        assert isinstance(full, trimesh.Trimesh)  # what force="mesh" loads
        view = FrameView(job_scene(r.mesh, full, gravity, material=spec.material, placement=spec.placement,
                                   impurity=p.surface.impurity,
                                   icicle_axes=r.trajectories.points),
                         load_render_config(spec.render))
    growing = Growing(r.trajectories, r.drips, p.surface, p.glaze, gravity, p.growth.frames,
                      object_usd=job_dir / OBJECT_USDC, scene_usd=job_dir / SCENE_USDA)
    result = grow_frames(
        job_dir / GROWTH_DIR, growing, view=view, progress=run.progress,
        build=lambda t, d, g, rng: build_surface(inputs, replace(r, trajectories=t, drips=d), rng, glaze=g),
        new_rng=lambda: stage_rng(spec.seed, Stage.SURFACE))
    return {"growth_frames": len(result.frames), "growth_seconds_per_frame": round(result.seconds_per_frame, 3)}


