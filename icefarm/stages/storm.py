"""A storm in physical units: where its water lands, freezes, runs and drips (``storm.mode: physical``).

The paper's knobs are relative to the object (normalised water, a fixed count of drip
points, glaze per meter of height), so a garden table and a 3 m house need hand tuning.
Here the weather sets the ice, whatever the asset's size:

* **Catch.** Rain falls along gravity, slanted by ``storm.wind`` (`icefarm.stages.rain`): a
  vertex under open sky catches the precipitation depth ``P`` over its area projected
  across the rain (``P cos(tilt) A`` in still air; walls facing the wind catch too); nothing
  lands under an overhang or in the lee. Meltwater comes from the snow on slopes under
  `SNOW_SLOPE_DEG`.
* **Freeze.** Each area freezes at most a share of the rain a level face gets
  (``storm.freeze``; ``storm.wall_freeze`` of that on vertical and downward faces, which
  lose less heat and shed their film faster): a heat budget, local to the area, so the
  glaze is as thick on a 0.3 m object as on a 3 m one. A flat top gains ``freeze P`` of
  water as ice (x `WATER_TO_ICE`); a horizontal bar, where nothing runs off, gains about
  ``P / pi`` of radial ice (Jones 1998). ``glaze.lifetime`` moves the budget up (0) or down
  (1) the walk of the water (Equation 3's dUp and dDown) around that amount.
* **Run off.** What does not freeze runs down every lower edge, by its slope (across level
  tops to their nearest edge), freezing a share per meter it runs (`RUNOUT_M`) where there is
  budget left.
* **Drip.** Where the surface turns towards gravity past the drip limit, the film sheds as
  the tilt rises (the share ``tilt - seen``, ``seen`` the largest tilt the water already
  passed, so a fine mesh sheds no faster than a coarse one); where the walk ends facing
  down, all of it drips; in a basin it pools, or with ``water.pools: overflow`` the full
  basin spills over its rim and the water runs on (`icefarm.stages.basins`).

Every drop is counted once: caught = frozen + shed + pooled (`StormBudget`). The water shed
along the drip rims feeds the icicles (`icefarm.stages.drips.find_drips` with ``flux``); a
share of it freezes on them, as much as the heat their surface loses over the storm allows,
the rest drips to the ground, and the ice volume gives the length through the icicle profile
(`icefarm.stages.icicle_size`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import cg
from scipy.spatial import cKDTree

from ..geometry import unit
from ..midpoint import split_long_edges
from ..params import StormParams
from .basins import spill_over, spill_routes
from .rain import FALL_SPEED, facing_rain, open_sky, rain_vector
from .runoff import film_routes, run_film

# Density of water and of glaze (clear, dense ice: 917 kg/m^3), kg/m^3; one meter of
# frozen water is 1.09 m of glaze (clear glaze is solid ice: Makkonen 2000, Phil. Trans. R. Soc. A 358).
RHO_WATER = 1000.0
RHO_ICE = 917.0
WATER_TO_ICE = RHO_WATER / RHO_ICE
# Radial ice of the utilities' freezing-rain classes, m: 0.25 in an ice storm, 0.5 in
# damaging, 1 in crippling (the US National Weather Service's ice-storm threshold, then the utilities' classes).
RADIAL_ICE_M = {"light": 0.00635, "moderate": 0.0127, "severe": 0.0254}
# Snow stays on slopes up to this many degrees from level (steeper roofs shed it): the
# meltwater storm melts it. Typical angle of repose of wet snow, 45-55 degrees.
SNOW_SLOPE_DEG = 50.0
# Meltwater: refreezes only this close (m) to the drip rims, the cold edges past the warm
# body (an eave past the heated wall): long icicles, little glaze elsewhere.
MELT_RIM_BAND = 0.1
# Water running over a surface freezes a share 1 - exp(-s / runout) of itself over s meters
# (within the area's budget): runout is this many meters at glaze.lifetime 0.5, in
# proportion to it (lt 0: it freezes where it lands). A rail's 6 cm side keeps a fifth of
# what runs over it; the rest drips from its underside as icicles.
RUNOUT_M = 0.25
# The glaze is relaxed over about this many meters of surface (`_spread`): a kernel of
# standard deviation half of it along each direction, whatever the mesh's resolution.
GLAZE_BLUR_M = 0.03
# Glaze thinner than this (m) is left out of the coat: it reads as a wet sheen, and a coat far
# thinner than its voxels tears into speckles and is slow to mesh (on a fence).
GLAZE_MIN_M = 0.001
# glaze.lifetime moves the freezing budget along the water's walk by at most this share
# (lt 0: 1.5x at the top, 0.5x at the bottom; lt 0.5: even).
LIFETIME_CONTRAST = 1.0
# A fountain's bowls spill one into the next: the overflow is followed down at most this
# many basins.
SPILL_CASCADE = 8
# Largest growth ratio (base radius added per meter of length) of a storm's icicle: a stub
# that thickened as the storm does is at most a cone half as wide as it is long.
GROWTH_MAX = 0.25



@dataclass(frozen=True)
class Constant:
    """A fixed quantity of the storm model, listed by ``icefarm params``."""

    name: str
    value: float
    unit: str
    domain: str
    source: str


def constants() -> tuple[Constant, ...]:
    """The storm model's constants with their units, domains and sources."""
    return (
        Constant("RHO_WATER", RHO_WATER, "kg/m^3", "> 0", "liquid water"),
        Constant("RHO_ICE", RHO_ICE, "kg/m^3", "> 0", "glaze, clear dense ice (Makkonen 2000)"),
        Constant("RADIAL_ICE_M[light]", RADIAL_ICE_M["light"], "m", "> 0", "NWS ice storm, 0.25 in"),
        Constant("RADIAL_ICE_M[moderate]", RADIAL_ICE_M["moderate"], "m", "> 0", "utilities' damaging class, 0.5 in"),
        Constant("RADIAL_ICE_M[severe]", RADIAL_ICE_M["severe"], "m", "> 0", "utilities' crippling class, 1 in"),
        Constant("SNOW_SLOPE_DEG", SNOW_SLOPE_DEG, "deg", "[0, 90]", "wet snow's angle of repose, 45-55"),
        Constant("MELT_RIM_BAND", MELT_RIM_BAND, "m", ">= 0", "cold eave past a warm wall (chosen by eye)"),
        Constant("RUNOUT_M", RUNOUT_M, "m", "> 0", "film run before 1 - 1/e of it freezes, at lifetime 0.5"),
        Constant("LIFETIME_CONTRAST", LIFETIME_CONTRAST, "-", "[0, 1]", "Equation 3's lt as a lean of the budget"),
        Constant("GROWTH_MAX", GROWTH_MAX, "m/m", "> 0", "stubbiest icicle: a cone half as wide as long"),
        Constant("FALL_SPEED", FALL_SPEED, "m/s", "> 0",
                 "freezing rain's drops (Jones 1998's terms; Gunn & Kinzer 1949)"),
    )

class StormKind(enum.Enum):
    """The two ways real icicles form."""

    FREEZING_RAIN = "freezing_rain"  # glaze on all the rain reaches, icicles at the drip rims
    MELTWATER = "meltwater"  # snow melting on the upper surfaces, long icicles at the eaves


def precipitation_m(intensity: str, precipitation_mm: float = 0.0) -> float:
    """The storm's precipitation depth in meters of water.

    ``precipitation_mm`` above 0 is taken as given; 0 takes the ``intensity`` class's depth:
    the precipitation that leaves its radial ice on a horizontal bar in still air, ``P =
    pi R rho_i / rho_w`` (Jones, Atmospheric Research 46, 87-97, 1998): light 18 mm,
    moderate 37 mm, severe 73 mm.
    """
    if precipitation_mm > 0:
        return precipitation_mm / 1000.0
    return math.pi * RADIAL_ICE_M[intensity] / WATER_TO_ICE


@dataclass(frozen=True)
class StormBudget:
    """Where the storm's water went, in cubic meters of water (caught = frozen + shed + pooled)."""

    caught: float
    frozen: float
    shed: float
    pooled: float


@dataclass(frozen=True)
class StormResult:
    """The storm on the flow mesh, per vertex.

    Attributes
    ----------
    sky : (n,) bool
        Vertex sees open sky against gravity (nothing of the object above it).
    catch : (n,) float
        Water landing at the vertex, m^3.
    ice : (n,) float
        Glaze thickness at the vertex, meters of ice (frozen water x `WATER_TO_ICE` over the
        vertex's area).
    shed : (n,) float
        Water dripping off at the vertex, m^3.
    budget : StormBudget
    """

    sky: np.ndarray
    catch: np.ndarray
    ice: np.ndarray
    shed: np.ndarray
    budget: StormBudget


def vertex_areas(mesh: trimesh.Trimesh) -> np.ndarray:
    """``(n,)`` a third of the area of each vertex's faces, m^2."""
    return np.bincount(np.asarray(mesh.faces).ravel(), weights=np.repeat(mesh.area_faces / 3.0, 3),
                       minlength=len(mesh.vertices))


@dataclass(frozen=True)
class StormOptions:
    """A physical storm as stage 1 runs it: the ``storm`` group with what it reads from others.

    Attributes
    ----------
    storm : StormParams
        The resolved ``storm`` group: its kind, precipitation (`precipitation_m`), freeze
        and wall freeze shares, wind.
    lifetime : float
        ``glaze.lifetime``: 0 puts the freezing budget high on the walk, 1 low, 0.5 evens it.
    drip_limit : float
        ``drips.drip_limit``: degrees from gravity within which a surface sheds its film.
    pools : {"ignore", "overflow"}
        ``water.pools``: ``overflow`` takes basins as full (a fountain's bowls, a gutter),
        so what pools in them spills over their rims and runs on
        (`icefarm.stages.basins.spill_routes`), down to the next basin or a drip rim.
    """

    storm: StormParams
    lifetime: float
    drip_limit: float
    pools: str = "ignore"


def walk_position(d_up: np.ndarray, d_down: np.ndarray) -> np.ndarray:
    """``(n,)`` where each vertex lies on its walk, from Algorithm 1's walked distances up and
    down (meters): 0 at the top, 1 at the bottom, 0.5 on no walk."""
    walk = np.asarray(d_up, dtype=np.float64) + np.asarray(d_down, dtype=np.float64)
    return np.divide(d_up, walk, out=np.full(len(walk), 0.5), where=walk > 0)


def accrete(mesh: trimesh.Trimesh, gravity, sky: np.ndarray, low: np.ndarray, options: StormOptions, *,
            rain=None, cast=None) -> StormResult:
    """Catch, freeze, run off and shed a storm's water over ``mesh``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The flow surface, in meters, outward normals.
    gravity : (3,) float
    sky : (n,) bool
        `icefarm.stages.rain.open_sky` of the vertices.
    low : (n,) float
        Where each vertex lies on its walk (`walk_position`): 0 at the top, 1 at the bottom.
    options : StormOptions
        The storm, the glaze's lifetime, the drip limit and what pools do.
    rain : (3,) float, optional
        `icefarm.stages.rain.rain_vector`: freezing rain slanted by the wind lands on the
        faces that turn towards it; None: along gravity.
    cast : callable, optional
        A `icefarm.spatial.ray_caster` of ``mesh`` to reuse (``overflow`` only).

    Returns
    -------
    StormResult
    """
    storm, lifetime = options.storm, options.lifetime
    precipitation = precipitation_m(storm.intensity, storm.precipitation)
    freeze, wall_freeze = storm.freeze, storm.wall_freeze
    kind = StormKind(storm.kind).value
    g = unit(np.asarray(gravity, dtype=np.float64))
    n = len(mesh.vertices)
    normals = np.asarray(mesh.vertex_normals)
    cos_up = normals @ -g
    area = vertex_areas(mesh)
    sky = np.asarray(sky, dtype=bool)
    if kind == StormKind.MELTWATER.value:
        snow = sky & (cos_up >= math.cos(math.radians(SNOW_SLOPE_DEG)))
        catch = precipitation * np.where(snow, cos_up, 0.0) * area
    else:
        catch = precipitation * np.where(sky, facing_rain(normals, g if rain is None else rain), 0.0) * area
    cos_limit = math.cos(math.radians(options.drip_limit))
    tilt = np.clip((normals @ g - cos_limit) / (1.0 - cos_limit), 0.0, 1.0)
    lean = 1.0 + LIFETIME_CONTRAST * (2.0 * lifetime - 1.0) * (low - 0.5)
    capacity = freeze * precipitation * area * lean * (wall_freeze + (1.0 - wall_freeze) * np.maximum(cos_up, 0.0))
    if kind == StormKind.MELTWATER.value:  # the warm body melts, the cold rims refreeze
        edges = np.asarray(mesh.edges_unique)
        edge_of_region = (tilt[edges[:, 0]] > 0) != (tilt[edges[:, 1]] > 0)
        rims = mesh.vertices[edges[edge_of_region].ravel()]
        near = cKDTree(rims).query(mesh.vertices, distance_upper_bound=MELT_RIM_BAND)[0] <= MELT_RIM_BAND \
            if len(rims) else np.zeros(n, dtype=bool)
        capacity = np.where(near, capacity, 0.0)
    start, target, share, step, order, outlet = film_routes(mesh, g, cos_up, area)
    runout = RUNOUT_M * 2.0 * lifetime
    passing = 1.0 - np.exp(-step / runout) if runout > 0 else np.ones(n)
    frozen, shed, pooled = run_film(catch, capacity, passing, tilt, (start, target, share), order, outlet)
    if options.pools == "overflow" and pooled.any():
        spills = spill_routes(mesh, g, cast)
        for _ in range(SPILL_CASCADE):
            arriving, kept = spill_over(pooled, spills)
            if not arriving.any():
                break
            f, s, p = run_film(arriving, capacity - frozen, passing, tilt, (start, target, share), order, outlet)
            frozen, shed, pooled = frozen + f, shed + s, kept + p
    ice = np.divide(_spread(mesh, frozen * WATER_TO_ICE, area), area, out=np.zeros(n), where=area > 0)
    ice[ice < GLAZE_MIN_M] = 0.0  # a film the blur thinned to nothing: no coat there
    budget = StormBudget(float(catch.sum()), float(frozen.sum()), float(shed.sum()), float(pooled.sum()))
    return StormResult(sky=sky, catch=catch, ice=ice, shed=shed, budget=budget)



def _spread(mesh: trimesh.Trimesh, volume: np.ndarray, area: np.ndarray) -> np.ndarray:
    """``(n,)`` ice volumes per vertex, m^3, relaxed over about `GLAZE_BLUR_M` of surface.

    One implicit step of diffusion, ``(diag(area) + tau L) t = volume`` for the thickness t,
    with L the mesh's Laplacian on positive edge weights (the faces' area by the edge over 1.5
    times its squared length: the cotangent weight on equilateral triangles) and ``tau`` so
    that the kernel's standard deviation is ``GLAZE_BLUR_M / 2`` along each direction
    (``2 tau``): the same on a coarse proxy as on a refined mesh. The matrix is an
    M-matrix whose rows of L sum to 0: the total stays the same, no thickness goes negative
    and an even coat stays even. Ice does not freeze vertex by vertex: the water each route
    carries would leave the glaze on walls in speckles and in sharp-edged fans, which the coat
    renders as black patches on a fence's pickets. One implicit step, not explicit passes (one
    edge each, at most 12): those relax a step over 6 to 7 mm (3/4 to 1/4 of it) on any mesh, a
    quarter of `GLAZE_BLUR_M`: under them a 25 cm teapot's spout, on a 7 mm proxy, keeps steps of 8 mm
    across one edge, and its coat meshes into a crumpled sheet of flaps.
    """
    edges = np.asarray(mesh.edges_unique)
    n = len(volume)
    v = np.asarray(volume, dtype=np.float64)
    if len(edges) == 0 or not (area > 0).any():
        return v
    face_area = np.bincount(np.asarray(mesh.faces_unique_edges).ravel(), weights=np.repeat(mesh.area_faces, 3),
                            minlength=len(edges))
    length2 = np.maximum(np.asarray(mesh.edges_unique_length) ** 2, 1e-30)
    weight = face_area / (1.5 * length2)
    tau = 0.5 * (0.5 * GLAZE_BLUR_M) ** 2
    a, b = edges[:, 0], edges[:, 1]
    lap = coo_matrix((np.r_[-weight, -weight], (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()
    degree = np.bincount(a, weights=weight, minlength=n) + np.bincount(b, weights=weight, minlength=n)
    # Vertices without area (none on a clean mesh) keep a unit diagonal: they hold no ice.
    mass = np.where(area > 0, area, 1.0)
    diagonal = mass + tau * degree
    system = (lap * tau + diags(diagonal)).tocsr()
    rhs = np.where(area > 0, v, 0.0)
    # Conjugate gradients from the unrelaxed coat (an even one is already the answer): 140
    # iterations on a car's 218 k vertices, about 20 times faster than a sparse LU there; skinny
    # faces (a box-modelled bench) take up to 550. The last round-off of the total is scaled away.
    t, _ = cg(system, rhs, x0=np.divide(v, area, out=np.zeros(n), where=area > 0), rtol=1e-10, atol=0.0,
              maxiter=5000, M=diags(1.0 / diagonal))
    out = np.maximum(t, 0.0) * np.where(area > 0, area, 0.0)
    total = out.sum()
    return out * (rhs.sum() / total) if total > 0 else out


def storm_water(mesh: trimesh.Trimesh, gravity, options: StormOptions, *, cast,
                source: trimesh.Trimesh | None = None):
    """Stage 1 under a physical storm: the supply is every upward vertex under open sky,
    Algorithm 1 walks on it (where each vertex lies on its walk) and `accrete` runs the storm.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The flow surface, in meters.
    gravity : (3,) float
    options : StormOptions
        The resolved ``storm`` group, the glaze's lifetime, the drip limit and what pools do.
    cast : callable
        A `icefarm.spatial.ray_caster` of ``mesh``.
    source : trimesh.Trimesh, optional
        ``water.source``: the storm falls only from this surface (a vertex must also see it
        straight up); None: the whole sky.

    Returns
    -------
    WaterResult
        With ``storm`` set; ``hits`` are the supply vertices.
    """
    from .water import WaterResult, water_coefficients

    storm = options.storm
    g = unit(np.asarray(gravity, dtype=np.float64))
    # Snow lies where it fell: only freezing rain drifts with the wind.
    rain = rain_vector(g, storm.wind) if storm.kind == StormKind.FREEZING_RAIN.value else g
    sky = open_sky(mesh, rain, cast)
    if source is not None and sky.any():
        from ..spatial import ray_caster

        under = np.flatnonzero(sky)
        back = -unit(rain)
        sky[under] = np.isfinite(ray_caster(source)(mesh.vertices[under], np.broadcast_to(back, (len(under), 3)))[0])
    supply = sky & (facing_rain(np.asarray(mesh.vertex_normals), rain) > 0)
    water, top, d_up, bottom, d_down = water_coefficients(mesh, supply, g)
    result = accrete(mesh, g, sky, walk_position(d_up, d_down), options, rain=rain, cast=cast)
    return WaterResult(supply=supply, water=water, top=top, d_up=d_up, bottom=bottom, d_down=d_down,
                       hits=np.asarray(mesh.vertices)[supply], storm=result)


# The refined flow surface holds about this many faces at most (a 3 m house at 2.5 cm
# edges would hold 760,000: 18 GB in the glaze coat); coarser edges past it.
FLOW_FACES = 150_000
# Midpoint subdivision leaves edges between half and all of the threshold: about
# FACES_PER_EDGE_AREA faces per square meter over the threshold squared.
FACES_PER_EDGE_AREA = 3.5


def refine(mesh: trimesh.Trimesh, max_edge: float) -> trimesh.Trimesh:
    """``mesh`` with every edge longer than ``max_edge`` meters split at its midpoint, until
    none is: the same surface exactly, conforming (no T-junctions), so it stays watertight
    (`icefarm.midpoint.split_long_edges`). The threshold grows so that the result holds about
    `FLOW_FACES` faces at most.

    Raises
    ------
    ValueError
        An edge shared by more than two faces (pymeshlab's subdivision, which this replaced,
        refused those too: the glaze then carries its water on the object as it is).
    """
    max_edge = max(max_edge, math.sqrt(FACES_PER_EDGE_AREA * float(mesh.area) / FLOW_FACES))
    if float(mesh.edges_unique_length.max(initial=0.0)) <= max_edge:
        return mesh
    welded = mesh.copy()  # seams of the same vertex twice are split on both sides alike
    welded.merge_vertices()
    if len(welded.faces) and np.bincount(welded.edges_unique_inverse).max() > 2:
        raise ValueError("midpoint refinement needs a mesh whose edges join at most two faces")
    vertices, faces = split_long_edges(welded.vertices, welded.faces, max_edge)
    return trimesh.Trimesh(vertices, faces, process=False)


def drip_rim_length(mesh: trimesh.Trimesh, region: np.ndarray, gravity, drip_limit: float) -> float:
    """Meters of drip rim: the edges where the drip region (faces ``region``) meets a face
    that does not face down past the drip limit (a slab's rim, an eave's edge, a belly's
    turn), each counted once."""
    if len(region) == 0:
        return 0.0
    in_region = np.zeros(len(mesh.faces), dtype=bool)
    in_region[region] = True
    downward = mesh.face_normals @ unit(np.asarray(gravity, dtype=np.float64)) >= math.cos(math.radians(drip_limit))
    a, b = mesh.face_adjacency.T
    rim = (in_region[a] & ~in_region[b] & ~downward[b]) | (in_region[b] & ~in_region[a] & ~downward[a])
    return float(np.linalg.norm(np.diff(mesh.vertices[mesh.face_adjacency_edges[rim]], axis=1), axis=2).sum())
