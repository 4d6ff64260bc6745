"""What each step of a job computes: pure functions of the job's inputs (`JobInputs`)
and the results of the steps before it (`StageResults`), declared in `icefarm.job.graph`.

What lies between the paper's stages lives here: the approximate surface for problem
meshes, the flow surface refined for water, drip points snapped back onto the object, the
normals a trajectory lifts off along, icicles stopped at the ground, painted overrides, the
landing water's ground ice, the surface the glaze grows on and the sole kept dry.
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .. import artifacts
from ..params import GlazeParams, Params
from ..placement import Placement, ground_height, ground_level, sole_vertices, stop_at_ground
from ..stages import (
    BRANCH_LIFE,
    DripOptions,
    DripResult,
    DripStorm,
    IcicleSizing,
    RainOptions,
    StormOptions,
    TrajectoryResult,
    WaterResult,
    compute_water,
    find_drips,
    grow_trajectories,
    growth_ratios,
    refine,
    storm_water,
    thickening_m,
    trajectory_options,
)
from .records import JobInputs, Stage, StageResults, stage_rng

# Over a wrap, object surface within this many times its alpha of the wrap takes the water
# there (the wrap lies up to about alpha off the object; the teapot's 99 % within 1.2 alpha).
WRAP_REACH = 2.0


@dataclass(frozen=True)
class IceFigures:
    """Stage 4's plausibility, measured on its mesh: `IcicleStats`, `FringeFigures`, `GlazeStats`."""

    icicles: Any
    fringe: Any
    glaze: Any


def proxy(i: JobInputs, r: StageResults) -> Any:
    """The approximate surface stages 1-2 run on, for problem meshes (paper 5.1)."""
    from ..stages import build_proxy

    return build_proxy(i.mesh, i.params.proxy, i.prepared.problems)


def flow(i: JobInputs, r: StageResults) -> trimesh.Trimesh:
    """The surface the water runs on: the object, or its proxy."""
    return i.mesh if r.proxy is None else r.proxy.mesh


def refine_flow(i: JobInputs, r: StageResults) -> trimesh.Trimesh:
    """The flow surface with no edge over ``storm.flow_edge``: large flat faces (box-modelled
    assets) carry no water from their middle to their rims, so a physical storm refines them."""
    if r.flow.edges_unique_length.max() > i.params.storm.flow_edge:
        return refine(r.flow, i.params.storm.flow_edge)
    return r.flow


def water(i: JobInputs, r: StageResults) -> WaterResult:
    """Stage 1, or the storm's water in physical units."""
    p, surface = i.params, r.flow
    source = i.source() if i.source else None
    if i.physical:
        options = StormOptions(p.storm, p.glaze.lifetime, p.drips.drip_limit, p.water.pools)
        result = storm_water(surface, i.gravity, options, cast=i.caster(surface), source=source)
    else:
        rain = RainOptions(p.water.rays, p.water.influence_radius, p.water.pools)
        result = compute_water(surface, i.gravity, rain, stage_rng(i.seed, Stage.WATER), source, i.caster(surface))
    if "water" in i.overrides:  # painted water replaces the coefficients and the storm, keeps the walks
        supply, painted = artifacts.read_water_ply(Path(i.overrides["water"]), len(surface.vertices))
        result = dataclasses.replace(result, supply=supply, water=painted, storm=None)
    return result


def drips(i: JobInputs, r: StageResults) -> DripResult:
    """Stage 2 on the flow surface, drip points moved onto the object."""
    if "drips" in i.overrides:
        return artifacts.drips_from_json(Path(i.overrides["drips"]))
    p, surface, wet = i.params, r.flow, r.water
    assert wet is not None
    d, kl = p.drips, p.trajectories.length_scale
    heights = surface.vertices @ -i.gravity
    grounded = heights < heights.min() + d.ground_clearance * np.ptp(heights)
    if i.physical and i.placement != Placement.GROUND.value:
        grounded[:] = False  # a hanging sign's lowest rim is where it drips, not where it stands
    storm = None
    if i.physical and wet.storm is not None:
        storm = DripStorm(wet.storm.shed, IcicleSizing(p.storm, p.surface, p.trajectories.branch_spread
                                                       if p.trajectories.division_probability > 0 else 0.0), kl)
    options = DripOptions(p.storm.max_icicles if i.physical else d.count, d.drip_limit, spacing=d.spacing,
                          distribution=d.distribution, min_fall=d.min_fall, min_water=d.min_length / kl,
                          floor=ground_level(i.placement, i.mesh, i.gravity), exclude_boxes=i.exclude,
                          exclude_vertices=grounded if d.ground_clearance > 0 else None)
    found = find_drips(surface, wet.water, i.gravity, options, stage_rng(i.seed, Stage.DRIPS),
                       caster=i.caster(surface), storm=storm)
    if storm is not None and len(found.positions):
        # Each icicle thickens as the storm does, whatever its water; and the glaze at the
        # rim swallows its first centimetres: it hangs its length below the ice.
        growth = growth_ratios(found.water * kl, thickening_m(p.storm, found.active), p.surface.growth_ratio)
        coat = wet.storm.ice[surface.faces[found.faces]].max(axis=1)
        found = dataclasses.replace(found, water=found.water + coat / kl, growth=growth)
    if surface is i.mesh:
        return found
    from ..stages import snap_to_surface

    points, normals, faces = snap_to_surface(found.positions, i.mesh, reference=found.normals)
    return dataclasses.replace(found, positions=points, normals=normals, faces=faces)


def trajectories(i: JobInputs, r: StageResults) -> TrajectoryResult:
    """Stage 3: the icicles' L-system axes, stopped at the ground."""
    p, obj, found = i.params, i.mesh, r.drips
    assert found is not None
    if "trajectories" in i.overrides:
        result = artifacts.trajectories_from_json(Path(i.overrides["trajectories"]))
    else:
        # Lift each start off the surface along its face normal; on a proxy run the snap
        # already turned normals towards the outside, which the face winding may not be.
        faces = np.clip(found.faces, 0, len(obj.faces) - 1)
        lift = found.normals if r.flow is not obj else np.where(
            (found.faces >= 0)[:, None], obj.face_normals[faces], found.normals)
        options = trajectory_options(p.trajectories, i.gravity, p.drips.drip_limit,
                                     branch_life=BRANCH_LIFE if i.physical else 1.0)
        result = grow_trajectories(obj, found.positions, lift, found.water, stage_rng(i.seed, Stage.TRAJECTORIES),
                                   options, caster=i.caster(obj))
    if found.growth is not None and result.n_branches:
        result = dataclasses.replace(result, branch_growth=found.growth[result.branch_icicle])
    if i.placement == Placement.GROUND.value:  # an icicle that reaches the ground stops at it
        result = stop_at_ground(result, i.gravity, ground_height(obj.vertices, i.gravity), p.surface.tip_radius)
    return result


def landing(i: JobInputs, r: StageResults) -> Any:
    """Where the water off the icicles' tips lands."""
    from ..stages import LandingOptions, find_landings

    gi, obj = i.params.ground_ice, i.mesh
    assert r.trajectories is not None and r.drips is not None
    options = LandingOptions(gi.runoff, gi.merge, floor=ground_level(i.placement, i.mesh, i.gravity))
    return find_landings(r.trajectories, r.drips.water, i.gravity, options, cast=i.caster(obj),
                         face_normals=obj.face_normals)


def ground_ice(i: JobInputs, r: StageResults) -> Any:
    """Mounds or stalagmites on the landing points, on their own stream: the icicles, bases
    and glaze draw what they drew without them."""
    from ..stages import ground_ice_balls

    return ground_ice_balls(r.landing, i.params.ground_ice, i.params.surface, i.gravity,
                            stage_rng(i.seed, Stage.SURFACE, 1), cast=i.caster(i.mesh),
                            floor=ground_level(i.placement, i.mesh, i.gravity))


def sole(flow: trimesh.Trimesh, params: Params, gravity: np.ndarray, placement: str) -> np.ndarray | None:
    """``(n,) bool``: flow-mesh vertices a grounded object stands on (no ice there); None when hanging."""
    clearance = params.drips.ground_clearance
    return (sole_vertices(flow.vertices, gravity, clearance)
            if placement == Placement.GROUND.value and clearance > 0 else None)


def wet(i: JobInputs, r: StageResults) -> Any:
    """The surface the glaze grows on and is measured on, with its water and its sole: the
    flow mesh's own, or over a wrap the object's, the water carried over
    (`icefarm.stages.surface.glaze.carry_water`).

    Returns
    -------
    icefarm.stages.surface.glaze.CoatSurface
    """
    from ..stages import CoatSurface, ProxyMethod, carry_water

    assert r.water is not None
    exclude = sole(r.flow, i.params, i.gravity, i.placement)
    wrap = r.proxy is not None and r.proxy.method is ProxyMethod.WRAP and r.flow is not i.mesh
    if wrap and i.params.glaze.mode != "none":
        return carry_water(i.mesh, r.flow, r.water, exclude, WRAP_REACH * r.proxy.alpha)
    return CoatSurface(r.flow, r.water, exclude)


def surface(i: JobInputs, r: StageResults) -> Any:
    """Stage 4 as a job runs it (`build_surface`)."""
    return build_surface(i, r, rng=stage_rng(i.seed, Stage.SURFACE))


def build_surface(i: JobInputs, r: StageResults, rng: np.random.Generator, glaze: GlazeParams | None = None) -> Any:
    """Stage 4 on ``r``'s drips and trajectories (growth frames pass their own, with their
    own ``glaze`` group and stream): icicles, bases and glaze, the sole kept dry, ice that
    the metaballs' blend pushed below the ground spread flat on it; no measurements.

    Returns
    -------
    IceResult
    """
    from ..stages import IceInputs, build_ice

    p = i.params
    assert r.water is not None and r.drips is not None and r.trajectories is not None
    glaze = p.glaze if glaze is None else glaze
    inputs = IceInputs(i.mesh, r.flow, r.water, r.drips, r.trajectories,
                       exclude=sole(r.flow, p, i.gravity, i.placement), coat_surface=r.wet,
                       extra_balls=None if r.ground is None else r.ground.balls, cast=i.caster(r.flow))
    ice = build_ice(inputs, p.surface, glaze, i.gravity, rng, measure=False, note=i.note)
    floor = ground_level(i.placement, i.mesh, i.gravity)
    if floor is None or len(ice.vertices) == 0:
        return ice
    g = np.asarray(i.gravity, dtype=np.float64)
    below = np.minimum(ice.vertices @ -g - floor, 0.0)
    if not below.any():
        return ice
    from ..metaballs.clean import clean_slivers
    from ..stages import SLIVER

    # Flattening can squash the faces of a foot into slivers: clean them as stage 4 does,
    # on the faces at a flattened vertex (only those can have become slivers).
    vertices, faces, kept = clean_slivers(ice.vertices + below[:, None] * g, ice.faces,
                                          SLIVER * p.surface.voxel_size, near=below < 0)
    bands = None if ice.bands is None else ice.bands[kept]
    return dataclasses.replace(ice, vertices=vertices, faces=faces, bands=bands)


def measure(i: JobInputs, r: StageResults) -> IceFigures:
    """Plausibility, measured on the ice mesh apart from the modelling (Table 2 times that):
    the icicles on their axes, the fringe, the glaze on the surface it grew on."""
    from ..stages import fringe_figures, measure_glaze, measure_icicles

    ice, coat, found = r.ice, r.wet, r.drips
    assert r.trajectories is not None and found is not None
    axes = ice.axes if ice.axes is not None else r.trajectories
    # The three measures share nothing, and their k-d queries, ray casts and array work
    # release the GIL: side by side they take about the longest one's time.
    with ThreadPoolExecutor(2) as pool:
        glaze = pool.submit(measure_glaze, ice.vertices, ice.faces,
                            dataclasses.replace(coat, exclude=_not_glaze(coat.mesh, found, coat.exclude, i.params)),
                            i.gravity)
        fringe = pool.submit(fringe_figures, ice.vertices, ice.faces, axes, i.gravity)
        icicles = measure_icicles(ice.vertices, ice.faces, axes, i.params.surface)
        return IceFigures(icicles, fringe.result(), glaze.result())


def _not_glaze(mesh: trimesh.Trimesh, found: DripResult, sole: np.ndarray | None, p: Params) -> np.ndarray:
    """Vertices of the glaze's surface whose ice is not glaze: the sole, and around each drip
    point the base and the icicle's root (within twice the base extent), which stand thicker."""
    out = np.zeros(len(mesh.vertices), dtype=bool) if sole is None else sole.copy()
    if len(found.positions):
        from scipy.spatial import cKDTree

        reach = 2 * max(p.surface.base_extent, p.surface.tip_radius)
        out |= cKDTree(found.positions).query(mesh.vertices)[0] < reach
    return out
