"""The stages chained as every job runs them, in one pure function: `run_stages`.

What lies between the stages lives here and nowhere else: the approximate surface for
problem meshes, the sole a standing object rests on, drip points snapped back onto the
object, the normals a trajectory lifts off along, icicles stopped at the ground, painted
overrides, the landing water's ground ice and each stage's random stream and cache key.
`icefarm.pipeline` wraps each step with its cache and timer (``step``) and writes each
result as it comes (``on_stage``); `icefarm.bench`, Table 2 and the tests call the same
function, bare or with a timer, so what they measure is what a job runs.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from . import artifacts
from .geometry import ray_caster
from .mesh import PreparedMesh
from .params import GlazeParams, Params
from .placement import Placement, ground_height, ground_level, sole_vertices, stop_at_ground
from .stage_cache import digest, file_digest
from .stages.drips import DripResult, find_drips
from .stages.icicle_size import BRANCH_LIFE, IcicleSizing, growth_ratios, thickening_m
from .stages.storm import refine, storm_water
from .stages.trajectories import TrajectoryResult, grow_trajectories
from .stages.water import WaterResult, compute_water


class Stage(enum.Enum):
    """The steps a job can stop after (``until``); RENDER is the pipeline's."""

    WATER = "water"
    DRIPS = "drips"
    TRAJECTORIES = "trajectories"
    SURFACE = "surface"
    RENDER = "render"


STAGE_ORDER = tuple(Stage)
# Over a wrap, object surface within this many times its alpha of the wrap takes the water
# there (the wrap lies up to about alpha off the object; the teapot's 99 % within 1.2 alpha).
WRAP_REACH = 2.0

Work = Callable[[], Any]
Step = Callable[[str, "str | None", Work], Any]
"""``step(name, key, work)`` runs ``work`` for step ``name`` and returns its result; ``key``
names the result in a cache (None: not cacheable)."""


@dataclass(frozen=True)
class StageResults:
    """Every stage's result, as far as the chain went (``until``).

    Attributes
    ----------
    mesh : trimesh.Trimesh
        The object, in meters: drip points lie on it, trajectories and bases grow from it.
    flow : trimesh.Trimesh
        The surface stages 1-2 ran on: ``mesh`` itself, or the proxy's mesh.
    proxy : ProxyResult or None
        The approximate surface, for problem meshes.
    proxy_reason : str or None
        Why the proxy was built.
    water, drips, trajectories : stage results or None
    landing : LandingResult or None
        Where the water off the tips lands (``ground_ice.mode`` other than none).
    ground : GroundIce or None
        The mounds or stalagmites on the landing points.
    ice : IceResult or None
        Stage 4, without measurements (the pipeline measures apart from the modelling).
    keys : dict
        Step name to the cache key its result was asked under.
    """

    mesh: trimesh.Trimesh
    flow: trimesh.Trimesh
    proxy: Any = None
    proxy_reason: str | None = None
    water: WaterResult | None = None
    drips: DripResult | None = None
    trajectories: TrajectoryResult | None = None
    landing: Any = None
    ground: Any = None
    ice: Any = None
    keys: dict = dataclasses.field(default_factory=dict)


def stage_rng(seed: int, stage: Stage, stream: int | None = None) -> np.random.Generator:
    """Each stage draws from its own stream, so a cached upstream stage changes nothing downstream."""
    key = [seed, STAGE_ORDER.index(stage)] + ([] if stream is None else [stream])
    return np.random.default_rng(key)


def stops(until: Stage | None, stage: Stage) -> bool:
    """Whether a chain asked to stop after ``until`` stops after ``stage``."""
    return until is not None and STAGE_ORDER.index(stage) >= STAGE_ORDER.index(until)


def _plain(name: str, key: str | None, work: Work) -> Any:
    return work()


def run_stages(prepared: PreparedMesh, params: Params, seed: int = 0, *, placement: str = "ground",
               exclude: tuple = (), overrides: Mapping[str, str | Path] | None = None,
               source: Callable[[], trimesh.Trimesh | None] | None = None, until: Stage | None = None,
               mesh_key: str = "", step: Step = _plain,
               on_stage: Callable[[str, StageResults], None] | None = None,
               note: Callable[[str], None] | None = None) -> StageResults:
    """Run stages 1-4 (and the ground ice) on a prepared mesh, as a job does.

    Parameters
    ----------
    prepared : PreparedMesh
        The object, cleaned and in meters (`icefarm.mesh.prepare`).
    params : mapping
        Resolved once (`icefarm.params.resolve`).
    seed : int
        Each stage draws from its own stream of this seed (`stage_rng`).
    placement : {"ground", "hanging"}
        A grounded object's icicles stop at the ground and its sole stays dry.
    exclude : tuple of ((3,), (3,))
        Boxes, in meters in the object's frame, where no icicle may hang.
    overrides : mapping, optional
        Stage name (``water``, ``drips``, ``trajectories``) to a file whose contents replace
        that stage's result (`icefarm.artifacts`); painted water keeps the computed walks.
    source : callable, optional
        Returns the rain source mesh (or None for the sky); called inside stage 1.
    until : Stage, optional
        Stop after this stage.
    mesh_key : str
        Identifies the mesh in the cache keys (`icefarm.pipeline` passes its content hash).
    step : callable
        ``step(name, key, work)`` runs each step (``proxy``, ``water``, ``drips``,
        ``trajectories``, ``landing``, ``ground_ice``, ``surface``): a cache, a timer or both.
    on_stage : callable, optional
        ``on_stage(name, results)`` after each step, with the results so far (files, stats).
    note : callable, optional
        ``note(text)``: what a long step is doing inside (stage 4's parts), for progress.

    Returns
    -------
    StageResults
    """
    overrides = dict(overrides or {})
    bad = set(overrides) - {"water", "drips", "trajectories"}
    if bad:
        raise ValueError(f"run_stages: no override for {sorted(bad)}; water, drips or trajectories")
    return _run(prepared, params, seed, placement, tuple(exclude), overrides, source, until, mesh_key, step,
                on_stage or (lambda name, results: None), note)


def _run(prepared, p, seed, placement, exclude, overrides, source, until, mesh_key, step, on_stage, note):
    obj = prepared.mesh
    gravity = p.gravity
    casters: dict[int, Callable] = {}

    def caster(mesh: trimesh.Trimesh) -> Callable:
        """One ray-tracing BVH per mesh, built by the first step that casts on it."""
        if id(mesh) not in casters:
            casters[id(mesh)] = ray_caster(mesh)
        return casters[id(mesh)]

    def override_digest(stage: str) -> str | None:
        return file_digest(overrides[stage]) if stage in overrides else None

    results = StageResults(mesh=obj, flow=obj)
    keys: dict[str, str | None] = {}

    def advance(name: str, key: str | None, work: Work, field: str) -> Any:
        """Run step ``name`` through ``step``, keep its value as ``field`` of the results."""
        nonlocal results
        keys[name] = key
        value = step(name, key, work)
        results = dataclasses.replace(results, keys=dict(keys), **{field: value})
        on_stage(name, results)
        return value

    # The approximate surface stages 1-2 run on, for problem meshes (paper 5.1).
    proxy_key = "none"
    if p.proxy.mode != "never":
        from .stages.proxy import build_proxy, proxy_reason

        reason = proxy_reason(prepared.problems, p.proxy.mode, p.proxy.face_budget)
        if reason:
            proxy_key = digest(mesh_key, p.proxy)
            results = dataclasses.replace(results, proxy_reason=reason)
            proxy = advance("proxy", proxy_key, lambda: build_proxy(obj, p.proxy, prepared.problems), "proxy")
            results = dataclasses.replace(results, flow=proxy.mesh)
    storm = p.storm
    physical = storm.mode == "physical"
    if physical and storm.flow_edge > 0 and results.flow.edges_unique_length.max() > storm.flow_edge:
        # Large flat faces (box-modelled assets) carry no water from their middle to their rims.
        results = dataclasses.replace(results, flow=refine(results.flow, storm.flow_edge))
    flow = results.flow

    water_key = digest(mesh_key, proxy_key, p.water, seed, override_digest("water"),
                       *((p.storm, p.glaze.lifetime, p.drips.drip_limit) if physical else ()))

    def water_stage() -> WaterResult:
        if physical:
            result = storm_water(flow, gravity, storm, lifetime=p.glaze.lifetime,
                                 drip_limit=p.drips.drip_limit, cast=caster(flow),
                                 source=source() if source else None, pools=p.water.pools)
        else:
            result = compute_water(flow, gravity, p.water.rays, p.water.influence_radius,
                                   stage_rng(seed, Stage.WATER), source() if source else None, caster(flow),
                                   pools=p.water.pools)
        if "water" in overrides:  # painted water replaces the coefficients, keeps the walks
            supply, water = artifacts.read_water_ply(Path(overrides["water"]), len(flow.vertices))
            # Painted water replaces the storm too: drips and glaze follow the paint (relative).
            result = dataclasses.replace(result, supply=supply, water=water, storm=None)
        return result

    water = advance("water", water_key, water_stage, "water")
    if stops(until, Stage.WATER):
        return results

    drips_key = digest(water_key, p.drips, exclude, placement, p.trajectories.length_scale,
                       override_digest("drips"),
                       *((p.surface.tip_radius, p.surface.growth_ratio, p.surface.profile,
                          p.trajectories.branch_spread, p.trajectories.division_probability)
                         if physical else ()))

    def drips_stage() -> DripResult:
        if "drips" in overrides:
            return artifacts.drips_from_json(Path(overrides["drips"]))
        d = p.drips
        heights = flow.vertices @ -gravity
        grounded = heights < heights.min() + d.ground_clearance * np.ptp(heights)
        if physical and placement != Placement.GROUND.value:
            grounded[:] = False  # a hanging sign's lowest rim is where it drips, not where it stands
        kl = p.trajectories.length_scale
        shed = sizing = None
        if physical and water.storm is not None:
            shed = water.storm.shed
            sizing = IcicleSizing(storm, p.surface, p.trajectories.branch_spread
                                  if p.trajectories.division_probability > 0 else 0.0)
        found = find_drips(flow, water.water, gravity, storm.max_icicles if physical else d.count,
                           d.drip_limit, stage_rng(seed, Stage.DRIPS),
                           exclude_boxes=exclude, exclude_vertices=grounded if d.ground_clearance > 0 else None,
                           caster=caster(flow), spacing=d.spacing, distribution=d.distribution,
                           min_fall=d.min_fall, floor=ground_level(placement, obj, gravity),
                           min_water=d.min_length / kl, shed=shed, sizing=sizing,
                           length_scale=kl)
        if shed is not None and len(found.positions):
            # Each icicle thickens as the storm does, whatever its water; and the glaze at the
            # rim swallows its first centimetres: it hangs its length below the ice.
            growth = growth_ratios(found.water * kl, thickening_m(storm, found.active), p.surface.growth_ratio)
            coat = water.storm.ice[flow.faces[found.faces]].max(axis=1)
            found = dataclasses.replace(found, water=found.water + coat / kl, growth=growth)
        if flow is obj:
            return found
        from .stages.proxy import snap_to_surface

        # Icicles hang from the real object: move each drip point onto it.
        points, normals, faces = snap_to_surface(found.positions, obj, reference=found.normals)
        return dataclasses.replace(found, positions=points, normals=normals, faces=faces)

    drips = advance("drips", drips_key, drips_stage, "drips")
    if stops(until, Stage.DRIPS):
        return results

    grounded = placement == Placement.GROUND.value
    traj_key = digest(drips_key, p.trajectories, p.drips.drip_limit, placement,
                      p.surface.tip_radius if grounded else None, override_digest("trajectories"))

    def trajectory_stage() -> TrajectoryResult:
        if "trajectories" in overrides:
            result = artifacts.trajectories_from_json(Path(overrides["trajectories"]))
        else:
            # Lift each start off the surface along its face normal; on a proxy run the snap
            # already turned normals towards the outside, which the face winding may not be.
            faces = np.clip(drips.faces, 0, len(obj.faces) - 1)
            lift = drips.normals if flow is not obj else np.where(
                (drips.faces >= 0)[:, None], obj.face_normals[faces], drips.normals)
            result = grow_trajectories(obj, drips.positions, lift, drips.water, gravity,
                                       stage_rng(seed, Stage.TRAJECTORIES), drip_limit=p.drips.drip_limit,
                                       caster=caster(obj), branch_life=BRANCH_LIFE if physical else 1.0,
                                       **dataclasses.asdict(p.trajectories))
        if drips.growth is not None and result.n_branches:
            result = dataclasses.replace(result, branch_growth=drips.growth[result.branch_icicle])
        if grounded:  # an icicle that reaches the ground stops at it
            result = stop_at_ground(result, gravity, ground_height(obj.vertices, gravity), p.surface.tip_radius)
        return result

    traj = advance("trajectories", traj_key, trajectory_stage, "trajectories")
    if stops(until, Stage.TRAJECTORIES):
        return results

    ground_balls, ground_key = None, None
    gi = p.ground_ice
    if gi.mode != "none":
        from .stages.landing import find_landings
        from .stages.surface.ground_ice import ground_ice_balls

        floor = ground_level(placement, obj, gravity)
        landing_key = digest(traj_key, gi.runoff, gi.merge)
        landing = advance("landing", landing_key, lambda: find_landings(
            traj, drips.water, gravity, runoff=gi.runoff, merge=gi.merge, cast=caster(obj),
            face_normals=obj.face_normals, floor=floor), "landing")
        # Its own stream: the icicles, bases and glaze draw what they drew without it.
        ground = advance("ground_ice", None, lambda: ground_ice_balls(
            landing, gi, p.surface, gravity, stage_rng(seed, Stage.SURFACE, 1), cast=caster(obj), floor=floor),
            "ground")
        ground_balls, ground_key = ground.balls, digest(landing_key, gi, p.surface)

    surface_key = digest(traj_key, p.surface, p.glaze, ground_key)
    advance("surface", surface_key, lambda: build_surface(
        obj, flow, water, drips, traj, p, gravity, stage_rng(seed, Stage.SURFACE), placement=placement,
        cast=caster(flow), extra_balls=ground_balls, note=note, proxy=results.proxy), "ice")
    return results


def sole(flow: trimesh.Trimesh, params: Params, gravity: np.ndarray, placement: str) -> np.ndarray | None:
    """``(n,) bool``: flow-mesh vertices a grounded object stands on (no ice there); None when hanging."""
    clearance = params.drips.ground_clearance
    return (sole_vertices(flow.vertices, gravity, clearance)
            if placement == Placement.GROUND.value and clearance > 0 else None)


def glaze_surface(obj: trimesh.Trimesh, flow: trimesh.Trimesh, water: WaterResult, exclude: np.ndarray | None,
                  glaze: GlazeParams, proxy=None):
    """The surface the glaze grows on (and is measured on), with its water and its sole
    (``exclude``, per flow-mesh vertex, `sole`): the flow mesh's own, or over a wrap
    (``proxy``, the `ProxyResult` ``flow`` came from) the object's, the water carried over
    (`icefarm.stages.surface.glaze.carry_water`).

    Returns
    -------
    icefarm.stages.surface.glaze.CoatSurface
    """
    from .stages.proxy import ProxyMethod
    from .stages.surface import CoatSurface, carry_water

    if proxy is not None and proxy.method is ProxyMethod.WRAP and flow is not obj and glaze.mode != "none":
        return carry_water(obj, flow, water, exclude, WRAP_REACH * proxy.alpha)
    return CoatSurface(flow, water, exclude)


def build_surface(obj: trimesh.Trimesh, flow: trimesh.Trimesh, water: WaterResult, drips: DripResult,
                  traj: TrajectoryResult, params: Params, gravity: np.ndarray, rng: np.random.Generator, *,
                  placement: str = "ground", glaze: GlazeParams | None = None, cast=None, extra_balls=None,
                  note=None, proxy=None):
    """Stage 4 as a job runs it (the sole kept dry, no measurements); growth frames pass
    their own drips, trajectories, ``glaze`` group and stream. The glaze grows on
    `glaze_surface` (over a wrap, ``proxy``: the object itself).

    Returns
    -------
    IceResult
    """
    from .stages.surface import build_ice

    glaze = params.glaze if glaze is None else glaze
    exclude = sole(flow, params, gravity, placement)
    coat_surface = glaze_surface(obj, flow, water, exclude, glaze, proxy)
    ice = build_ice(obj, flow, water, drips, traj, params.surface, glaze, gravity, rng, exclude=exclude, cast=cast,
                    measure=False,
                    extra_balls=extra_balls, note=note, coat_surface=coat_surface)
    floor = ground_level(placement, obj, gravity)
    if floor is None or len(ice.vertices) == 0:
        return ice
    # Ice cannot sink into the ground: a foot the metaballs' blend pushed a hair below it
    # (fat stubs bulge past their balls) spreads flat on it instead.
    g = np.asarray(gravity, dtype=np.float64)
    below = np.minimum(ice.vertices @ -g - floor, 0.0)
    if not below.any():
        return ice
    from .metaballs.clean import clean_slivers
    from .stages.surface.build import SLIVER

    # Flattening can squash the faces of a foot into slivers: clean them as stage 4 does,
    # on the faces at a flattened vertex (only those can have become slivers).
    vertices, faces, kept = clean_slivers(ice.vertices + below[:, None] * g, ice.faces,
                                          SLIVER * params.surface.voxel_size, near=below < 0)
    bands = None if ice.bands is None else ice.bands[kept]
    return dataclasses.replace(ice, vertices=vertices, faces=faces, bands=bands)
