"""Run one job: prepare the mesh, the four stages, the scene and the render.

Every stage result is cached under a key made from the hashes of its inputs and of the
parameters it reads, so a sweep over surface parameters reuses stages 1-3 and one over
trajectory parameters reuses stages 1-2. Artifacts follow DESIGN.md; ``done.json`` comes
last and atomically, ``error.json`` names the failed stage.
"""

from __future__ import annotations

import enum
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from . import artifacts
from .errors import InputError
from .geometry import ray_caster
from .jobdir import DONE, ERROR, PARAMS, TIMINGS
from .mesh import PreparedMesh, prepare
from .placement import Placement, ground_height, ground_level, sole_vertices, stop_at_ground
from .scene.camera import frame_boxes
from .stage_cache import StageCache, digest as _digest, file_digest as _file_digest
from .stages.drips import DripResult, find_drips
from .stages.trajectories import TrajectoryResult, grow_trajectories, measure_trajectories
from .stages.water import WaterResult, compute_water

GENERATOR_PREFIX = "generator:"


class Stage(enum.Enum):
    WATER = "water"
    DRIPS = "drips"
    TRAJECTORIES = "trajectories"
    SURFACE = "surface"
    RENDER = "render"


STAGE_ORDER = tuple(Stage)


@dataclass(frozen=True)
class JobSpec:
    """Everything that defines one job; its hash is the job id.

    ``mesh`` is an absolute path or ``generator:NAME``; ``params`` is
    `icefarm.params.resolve` output; ``exclude`` holds boxes ``((lo), (hi))`` in meters in
    the object's frame; ``overrides`` pairs a stage name with a file that replaces its
    result; ``render`` is a render config name or path, None for no render; ``placement``
    is ``ground`` (the object stands on the ground plane) or ``hanging``.
    """

    object_id: str
    mesh: str
    size_m: float
    params: dict
    seed: int = 0
    render: str | None = None
    exclude: tuple = ()
    overrides: tuple = ()
    material: tuple = ()
    placement: str = "ground"


@dataclass(frozen=True)
class JobOutcome:
    status: str
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
    from .scene.config import load_render_config, render_config_to_dict

    return _digest(render_config_to_dict(load_render_config(render)))


def job_id(spec: JobSpec) -> str:
    """Short stable hash of mesh content, size, params, render config, seed and extras."""
    return _digest(
        mesh_digest(spec.mesh), spec.size_m, spec.params, render_digest(spec.render), spec.seed,
        spec.exclude, [(stage, _file_digest(path)) for stage, path in spec.overrides], spec.material,
        spec.placement,
    )[:12]


def load_object(spec: JobSpec) -> PreparedMesh:
    """The job's mesh, cleaned and in meters."""
    gravity = spec.params["water"]["gravity"]
    if spec.mesh.startswith(GENERATOR_PREFIX):
        from .generators import generate

        return prepare(generate(spec.mesh[len(GENERATOR_PREFIX):]), spec.size_m, gravity)
    return prepare(spec.mesh, spec.size_m, gravity)


def _rng(seed: int, stage: Stage) -> np.random.Generator:
    """Each stage has its own stream, so a cached upstream stage changes nothing downstream."""
    return np.random.default_rng([seed, STAGE_ORDER.index(stage)])


def _load_source(spec: JobSpec, prepared: PreparedMesh) -> trimesh.Trimesh | None:
    """The rain source surface, in the object's frame (same scale and offset)."""
    source = spec.params["water"]["source"]
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

    def timed(self, stage: str, work: Callable[[], Any]) -> Any:
        self.stage = stage
        start = time.perf_counter()
        value = work()
        self.seconds[stage] = round(time.perf_counter() - start, 6)
        # What fails before the next step starts (glue, imports, a config read) is not this
        # step's fault: error.json says "after <step>", not "<step>".
        self.stage = f"after {stage}"
        return value


def run_job(spec: JobSpec, job_dir: Path, cache_dir: Path | None = None,
            until: Stage | None = None, progress: bool = False) -> JobOutcome:
    """Run one job into ``job_dir``; never raises for a failure of the job itself.

    A failure writes ``error.json`` (stage, message, traceback) and returns status
    ``failed``; success writes ``done.json`` last. ``until`` stops after that stage;
    ``progress`` shows progress bars on long work (a render in several passes).
    """
    job_dir = Path(job_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    for stale in (DONE, ERROR):
        (job_dir / stale).unlink(missing_ok=True)
    run, cache = _Run(progress=progress), StageCache(Path(cache_dir) if cache_dir else None)
    try:
        summary = _run_stages(spec, job_dir, run, cache, until)
    except Exception as exc:
        message = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
        artifacts.write_json(job_dir / ERROR, {
            "stage": run.stage, "message": message, "traceback": traceback.format_exc(),
            "seconds": run.seconds,
        })
        return JobOutcome("failed", dict(run.seconds), tuple(cache.reused), run.stage, message)
    artifacts.write_json(job_dir / TIMINGS, {"seconds": run.seconds, **summary, "reused": cache.reused})
    # Last, and listing every artifact with its size and digest: `--resume` checks them.
    artifacts.write_json(job_dir / DONE, {
        "job": spec.object_id, "seconds": run.seconds, "reused": cache.reused, **summary,
        **({"cache_warnings": cache.warnings} if cache.warnings else {}),
        "artifacts": artifacts.list_artifacts(job_dir),
    })
    return JobOutcome("done", dict(run.seconds), tuple(cache.reused))


def _stops(until: Stage | None, stage: Stage) -> bool:
    return until is not None and STAGE_ORDER.index(stage) >= STAGE_ORDER.index(until)


def _run_stages(spec: JobSpec, job_dir: Path, run: _Run, cache: StageCache, until: Stage | None) -> dict:
    p = spec.params
    gravity = np.asarray(p["water"]["gravity"], dtype=np.float64)
    gravity = gravity / np.linalg.norm(gravity)
    overrides = dict(spec.overrides)
    artifacts.write_yaml(job_dir / PARAMS, p)
    prepared = run.timed("prepare", lambda: load_object(spec))
    obj = prepared.mesh
    mesh_key = _digest(mesh_digest(spec.mesh), spec.size_m, p["water"]["gravity"])
    stats: dict[str, Any] = {"input_faces": prepared.problems.faces, "problems": vars(prepared.problems),
                             "placement": spec.placement}

    flow, proxy_key = obj, "none"
    if p["proxy"]["mode"] != "never":
        from .proxy import build_proxy, proxy_reason

        reason = proxy_reason(prepared.problems, p["proxy"]["mode"], p["proxy"]["face_budget"])
        if reason:
            proxy_key = _digest(mesh_key, p["proxy"])
            proxy = run.timed("proxy", lambda: cache.get("proxy", proxy_key, lambda: build_proxy(obj, p["proxy"], prepared.problems)))
            flow = proxy.mesh
            artifacts.write_mesh(job_dir / "proxy.ply", flow)
            stats.update(proxy_reason=reason, proxy_faces=proxy.faces, proxy_components=proxy.components,
                         proxy_build_seconds=proxy.seconds)
    stats["flow_faces"] = len(flow.faces)
    casters: dict[int, Callable] = {}

    def caster(mesh: trimesh.Trimesh) -> Callable:
        """One ray-tracing BVH per mesh, shared by the stages that cast rays on it."""
        if id(mesh) not in casters:
            casters[id(mesh)] = ray_caster(mesh)
        return casters[id(mesh)]

    water_key = _digest(mesh_key, proxy_key, p["water"], spec.seed,
                        _file_digest(overrides["water"]) if "water" in overrides else None)

    def water_stage() -> WaterResult:
        source = _load_source(spec, prepared)
        result = compute_water(flow, gravity, p["water"]["rays"], p["water"]["influence_radius"],
                               _rng(spec.seed, Stage.WATER), source, caster(flow), pools=p["water"]["pools"])
        if "water" in overrides:  # painted water replaces the coefficients, keeps the walks
            supply, water = artifacts.read_water_ply(Path(overrides["water"]), len(flow.vertices))
            result = WaterResult(supply, water, result.top, result.d_up, result.bottom, result.d_down, result.hits)
        return result

    water = run.timed("water", lambda: cache.get("water", water_key, water_stage))
    artifacts.write_water_ply(job_dir / "water.ply", flow, water.supply, water.water)
    if _stops(until, Stage.WATER):
        return stats

    drips_key = _digest(water_key, p["drips"], spec.exclude, spec.placement, p["trajectories"]["length_scale"],
                        _file_digest(overrides["drips"]) if "drips" in overrides else None)

    def drips_stage() -> DripResult:
        if "drips" in overrides:
            return artifacts.drips_from_json(Path(overrides["drips"]))
        heights = flow.vertices @ -gravity
        grounded = heights < heights.min() + p["drips"]["ground_clearance"] * np.ptp(heights)
        found = find_drips(flow, water.water, gravity, p["drips"]["count"], p["drips"]["drip_limit"],
                           _rng(spec.seed, Stage.DRIPS), exclude_boxes=spec.exclude,
                           exclude_vertices=grounded if p["drips"]["ground_clearance"] > 0 else None,
                           caster=caster(flow), spacing=p["drips"]["spacing"],
                           distribution=p["drips"]["distribution"], min_fall=p["drips"]["min_fall"],
                           floor=ground_level(spec.placement, obj, gravity),
                           min_water=p["drips"]["min_length"] / p["trajectories"]["length_scale"])
        if flow is obj:
            return found
        from .proxy import snap_to_surface

        # Icicles hang from the real object: move each drip point onto it.
        points, normals, faces = snap_to_surface(found.positions, obj)
        return DripResult(found.region_faces, points, normals, found.water, faces)

    drips = run.timed("drips", lambda: cache.get("drips", drips_key, drips_stage))
    artifacts.write_json(job_dir / "drips.json", artifacts.drips_to_json(drips))
    stats["icicles"] = len(drips.positions)
    if _stops(until, Stage.DRIPS):
        return stats

    traj_key = _digest(drips_key, p["trajectories"], p["drips"]["drip_limit"], spec.placement,
                       p["surface"]["tip_radius"] if spec.placement == Placement.GROUND.value else None,
                       _file_digest(overrides["trajectories"]) if "trajectories" in overrides else None)

    def trajectory_stage() -> TrajectoryResult:
        result = grown_trajectories()
        if spec.placement == Placement.GROUND.value:  # an icicle that reaches the ground stops at it
            result = stop_at_ground(result, gravity, ground_height(obj.vertices, gravity), p["surface"]["tip_radius"])
        return result

    def grown_trajectories() -> TrajectoryResult:
        if "trajectories" in overrides:
            return artifacts.trajectories_from_json(Path(overrides["trajectories"]))
        # Lift each start off the surface along its face normal; on a proxy run the snap
        # already turned normals towards the outside, which the face winding may not be.
        faces = np.clip(drips.faces, 0, len(obj.faces) - 1)
        lift = drips.normals if flow is not obj else np.where(
            (drips.faces >= 0)[:, None], obj.face_normals[faces], drips.normals)
        return grow_trajectories(obj, drips.positions, lift, drips.water, gravity,
                                 _rng(spec.seed, Stage.TRAJECTORIES), drip_limit=p["drips"]["drip_limit"],
                                 caster=caster(obj), **p["trajectories"])

    traj = run.timed("trajectories", lambda: cache.get("trajectories", traj_key, trajectory_stage))
    artifacts.write_json(job_dir / "trajectories.json", artifacts.trajectories_to_json(traj))
    t = measure_trajectories(traj, gravity)
    stats.update(branches=traj.n_branches, upward_share=_finite(t.upward_share),
                 branch_spread_mm=_finite(t.branch_spread_mm), length_cv=_finite(t.length_cv),
                 trunk_lengths_m=_finite_list(t.trunk_lengths, 4))
    if not _stops(until, Stage.TRAJECTORIES):
        ground, ground_key = _ground_ice(spec, job_dir, run, cache, obj, drips, traj, gravity, traj_key,
                                         caster(obj), stats)
        stats.update(_surface_and_render(spec, job_dir, run, cache, until, obj, flow, water, drips, traj,
                                         gravity, _digest(traj_key, p["surface"], p["glaze"], ground_key),
                                         caster(flow), extra_balls=ground))
        if p["growth"]["frames"] and until is None:  # growth/: stages 1-3 as they are, stage 4 per frame
            stats.update(run.timed("growth", lambda: _growth(spec, job_dir, run, obj, flow, water, drips, traj,
                                                             gravity, caster(flow), ground)))
    return stats


def _ground_ice(spec, job_dir, run, cache, obj, drips, traj, gravity, traj_key, cast, stats):
    """Landing points of the water off the tips and the mounds or stalagmites on them
    (``ground_ice.mode``); writes landing.json. Nothing at all with mode none.

    Returns
    -------
    balls : Balls or None
        For the icicles' field.
    key : str or None
        What the surface's cache key must add.
    """
    from .stages.landing import find_landings
    from .stages.surface.ground_ice import ground_ice_balls

    p = spec.params
    gi = p["ground_ice"]
    if gi["mode"] == "none":
        return None, None
    floor = ground_level(spec.placement, obj, gravity)
    key = _digest(traj_key, gi["runoff"], gi["merge"])
    landing = run.timed("landing", lambda: cache.get("landing", key, lambda: find_landings(
        traj, drips.water, gravity, runoff=gi["runoff"], merge=gi["merge"], cast=cast,
        face_normals=obj.face_normals, floor=floor)))
    # Its own stream: the icicles, bases and glaze draw what they drew without it.
    rng = np.random.default_rng([spec.seed, STAGE_ORDER.index(Stage.SURFACE), 1])
    ground = run.timed("ground_ice", lambda: ground_ice_balls(landing, gi, p["surface"], gravity, rng,
                                                               cast=cast, floor=floor))
    artifacts.write_json(job_dir / "landing.json", artifacts.landing_to_json(landing, ground.heights, ground.columns))
    grown = ground.heights[ground.heights > 0] * 1000
    stats.update(landing_points=len(landing), stalagmites=len(grown), columns=int(ground.columns.sum()),
                 stalagmite_median_mm=_finite(np.median(grown)) if len(grown) else None,
                 stalagmite_max_mm=_finite(grown.max()) if len(grown) else None)
    return ground.balls, _digest(key, gi, p["surface"])


def _surface_and_render(spec, job_dir, run, cache, until, obj, flow, water, drips, traj, gravity, key,
                        cast, extra_balls=None) -> dict:
    from .stages.surface.glaze import measure_glaze
    from .stages.surface.measure import measure_icicles

    p = spec.params
    sole = _sole(spec, flow, gravity)
    ice = run.timed("surface", lambda: cache.get("surface", key, lambda: _build_ice(
        spec, obj, flow, water, drips, traj, gravity, cast, extra_balls)))
    ice_mesh = trimesh.Trimesh(ice.vertices, ice.faces, process=False)
    artifacts.write_mesh(job_dir / "ice.ply", ice_mesh)
    # Plausibility, measured on the mesh: timed apart from the modelling (Table 2 times that).
    m, glaze = run.timed("measure", lambda: (
        measure_icicles(ice.vertices, ice.faces, traj, p["surface"]),
        measure_glaze(ice.vertices, ice.faces, flow, water, gravity,
                      exclude=_not_glaze(flow, drips, sole, p["surface"]))))
    stats = {
        "glaze_coverage": _finite(glaze.coverage), "glaze_p10_mm": _finite(glaze.p10_mm),
        "glaze_p50_mm": _finite(glaze.p50_mm), "glaze_p90_mm": _finite(glaze.p90_mm),
        "glaze_top_bottom": _finite(glaze.top_bottom),
        "ice_faces": len(ice.faces), "metaballs": ice.balls, "tip_radius_mm": _finite(m.tip_radius_mm),
        "taper": _finite_list(m.taper), "growth_ratio": _finite_list(m.growth_ratio, 4),
        "profile_exponent": _finite_list(m.profile_exponent),
        "ripple_amplitude_mm": _finite(m.ripple_amplitude_mm), "ripple_wavelength_cm": _finite(m.ripple_wavelength_cm),
    }
    if p["surface"]["curtain"] > 0:
        stats["curtain_area_m2"] = round(ice.curtain_area, 6)
    if spec.render is None or _stops(until, Stage.SURFACE):
        return stats
    from .scene.config import load_render_config, material_from_dict
    from .scene.render import render_job, write_scenes

    config = load_render_config(spec.render)
    material = material_from_dict(dict(spec.material))

    def render() -> Any:
        files = write_scenes(job_dir, obj, ice_mesh if len(ice.faces) else None, config, gravity, material,
                             frame_points=frame_boxes(obj, ice_mesh), defer_povray=True,
                             impurity=p["surface"]["impurity"],  # impure water: a cloudy core
                             ground_level=ground_level(spec.placement, obj, gravity))
        if files.ground_height is not None:  # 0 for a grounded object; a hanging one floats
            stats["ground_gap_mm"] = _finite((ground_height(obj.vertices, gravity) - files.ground_height) * 1000)
        return render_job(job_dir, config, files, progress=run.progress)  # POV-Ray files written meanwhile

    result = run.timed("render", render)
    stats.update(object_material=material, render_variant=result.variant, render_integrator=result.integrator,
                 renderer=result.renderer,
                 render_seconds=result.seconds, scene_seconds=result.scene_seconds,
                 scene_write_seconds=result.write_seconds, scene_load_seconds=result.load_seconds,
                 scene_wait_seconds=result.wait_seconds,
                 povray_write_cpu_seconds=result.povray_write_cpu_seconds)
    from .usd import write_job_usd

    # scene.usda (object.usdc, ice.usdc) for DCCs: the render's cameras, sun, sky, materials.
    run.timed("usd", lambda: write_job_usd(job_dir, material=material, ice_mesh=ice_mesh))
    return stats


def _sole(spec: JobSpec, flow: trimesh.Trimesh, gravity: np.ndarray) -> np.ndarray | None:
    """Flow-mesh vertices a grounded object stands on (no ice there); None when hanging."""
    clearance = spec.params["drips"]["ground_clearance"]
    return (sole_vertices(flow.vertices, gravity, clearance)
            if spec.placement == Placement.GROUND.value and clearance > 0 else None)


def _build_ice(spec, obj, flow, water, drips, traj, gravity, cast, extra_balls, glaze=None, rng=None):
    """Stage 4 as the job runs it; growth frames pass their own drips, glaze and stream."""
    from .stages.surface import build_ice

    p = spec.params
    return build_ice(obj, flow, water, drips, traj, p["surface"], p["glaze"] if glaze is None else glaze, gravity,
                     _rng(spec.seed, Stage.SURFACE) if rng is None else rng, exclude=_sole(spec, flow, gravity),
                     cast=cast, measure=False, extra_balls=extra_balls)


def _growth(spec, job_dir, run, obj, flow, water, drips, traj, gravity, cast, extra_balls) -> dict:
    """``growth/``: the ice at ``growth.frames`` moments of its growth (`icefarm.growth`),
    rendered with the job's camera: the one framed on the full-grown ice."""
    from .growth import FrameView, grow_frames

    p = spec.params
    view = None
    if spec.render is not None:
        from .scene.config import load_render_config, material_from_dict

        full = trimesh.load(job_dir / "ice.ply", process=False, force="mesh")
        view = FrameView(obj, load_render_config(spec.render), gravity, material_from_dict(dict(spec.material)),
                         frame_boxes(obj, full), p["surface"]["impurity"], ground_level(spec.placement, obj, gravity))
    result = grow_frames(
        job_dir / "growth", traj, drips, p["surface"], p["glaze"], frames=p["growth"]["frames"],
        build=lambda t, d, g, rng: _build_ice(spec, obj, flow, water, d, t, gravity, cast, extra_balls, g, rng),
        new_rng=lambda: _rng(spec.seed, Stage.SURFACE), gravity=gravity, view=view, progress=run.progress,
        object_usd=job_dir / "object.usdc")
    return {"growth_frames": len(result.frames), "growth_seconds_per_frame": round(result.seconds_per_frame, 3)}


def _not_glaze(flow: trimesh.Trimesh, drips: DripResult, sole: np.ndarray | None, surface: dict) -> np.ndarray:
    """Flow-mesh vertices whose ice is not glaze: the sole, and around each drip point the
    base and the icicle's root (within twice the base extent), which stand thicker."""
    out = np.zeros(len(flow.vertices), dtype=bool) if sole is None else sole.copy()
    if len(drips.positions):
        from scipy.spatial import cKDTree

        out |= cKDTree(drips.positions).query(flow.vertices)[0] < 2 * max(surface["base_extent"], surface["tip_radius"])
    return out


def _finite(value: float) -> float | None:
    """JSON has no NaN: an unmeasured value is null."""
    return float(value) if np.isfinite(value) else None


def _finite_list(values: np.ndarray, digits: int = 3) -> list[float | None]:
    """Per-icicle figures for JSON, aligned with the trunks: an unmeasured one is null."""
    return [round(float(x), digits) if np.isfinite(x) else None for x in values]
