"""Stage 2 (paper 4.2): the drip region and the drip points on it.

The paper spreads the drip points uniformly over the drip region (``distribution: area``).
Real water leaves a surface where it first meets one it cannot cling to, so by default
(``distribution: water``) the points go where the water drips off: each vertex's water
runs down its walk (Algorithm 1's chains) into the region and drips in proportion to how
far the region's faces there turn towards gravity (`drip_flux`). A sharp lip or an eave's
edge sheds nearly all of it; a smooth dome sheds it evenly over its area (as the paper);
what is left drips at the region's lowest points. Points never lie closer than
``spacing`` (icicles settle 2.3 to 2.5 cm apart), and each icicle's water is the water
its stretch of the rim sheds (`icefarm.stages.rims`), so icicles that drain more grow longer.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from ..geometry import perpendicular_basis, sample_faces, unit
from ..spatial import inside, ray_caster
from ..tol import tol
from .dart_throwing import spaced
from .rims import (
    FUSE_MARGIN,
    HEAT_SPREAD,
    RIM_REACH,
    SAMPLES_PER_SPACING,
    catchment_volume,
    catchment_water,
    compete,
    drip_flux,
    rim_half_edges,
    rim_points,
    swallow,
)


@dataclass(frozen=True)
class DripResult:
    """Where the water drips.

    Attributes
    ----------
    region_faces : (m,) int
        Faces of the drip region.
    positions : (k, 3) float
        Drip points, in meters.
    normals : (k, 3) float
        Unit surface normals at the drip points (interpolated vertex normals).
    water : (k,) float
        Water of each drip point's icicle, in meters of water coefficient: interpolated at
        the point (``distribution: area``, the paper) or drained from its stretch of rim
        (``water``, `catchment_water`).
    faces : (k,) int
        Face holding each drip point.
    active : (k,) float or None
        A physical storm's share of the storm each icicle was fed while its neighbours
        competed for the rim (`icefarm.stages.rims.compete`); None: all of it.
    growth : (k,) float or None
        A physical storm's growth ratio of each drip point's icicle (`icefarm.stages.icicle_size.
        growth_ratios`); None: ``surface.growth_ratio``.
    """

    region_faces: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    water: np.ndarray
    faces: np.ndarray
    growth: np.ndarray | None = None
    active: np.ndarray | None = None


def drip_criterion(normals: np.ndarray, gravity: np.ndarray, drip_limit: float) -> np.ndarray:
    """``(n,) bool``: each unit normal ``(n, 3)`` lies within ``drip_limit`` degrees of gravity."""
    return normals @ unit(gravity) >= np.cos(np.radians(drip_limit))


def excluded_vertices(vertices: np.ndarray, boxes=()) -> np.ndarray:
    """``(n,) bool``: vertices inside any box ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` (a job's
    `icefarm.job.pipeline.Box` is such a pair)."""
    inside = np.zeros(len(vertices), dtype=bool)
    for lo, hi in boxes:
        inside |= np.all((vertices >= np.asarray(lo)) & (vertices <= np.asarray(hi)), axis=1)
    return inside


def drip_region(mesh: trimesh.Trimesh, water: np.ndarray, gravity, drip_limit: float,
                excluded: np.ndarray | None = None) -> np.ndarray:
    """Faces with a wet vertex whose vertex normals all meet the drip criterion.

    Parameters
    ----------
    water : (n,) float
        Water coefficient per vertex.
    excluded : (n,) bool, optional
        Vertices where no icicle may hang; faces touching them leave the region.

    Returns
    -------
    (m,) int
        Face indices of the drip region.
    """
    ok = drip_criterion(mesh.vertex_normals, gravity, drip_limit)
    if excluded is not None:
        ok &= ~excluded
    faces = mesh.faces
    region = ok[faces].all(axis=1) & (water[faces] > 0).any(axis=1)
    return np.flatnonzero(region)


def _transition_points(mesh: trimesh.Trimesh, water: np.ndarray, ok: np.ndarray, count: int,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Drip points on edges and vertices that meet the criterion where no whole face does.

    Coarse, highly curved meshes (paper 4.2) can meet the criterion at a vertex or along
    an edge while no face meets it at all three vertices.

    Returns
    -------
    corners : (k, 3) int
        Vertices each point interpolates.
    weights : (k, 3) float
        Their weights (the third is 0 on an edge; a vertex gets weight 1).
    """
    edges = mesh.edges_unique
    good = ok[edges].all(axis=1) & (water[edges] > 0).any(axis=1)
    edges, lengths = edges[good], mesh.edges_unique_length[good]
    if lengths.sum() > 0:
        ends = edges[rng.choice(len(edges), size=count, p=lengths / lengths.sum())]
        s = rng.random(count)
        return np.column_stack([ends, ends[:, 0]]), np.column_stack([1 - s, s, np.zeros(count)])
    candidates = np.flatnonzero(ok & (water > 0))
    chosen = rng.choice(candidates, size=min(count, len(candidates)), replace=False)
    return np.repeat(chosen[:, None], 3, axis=1), np.tile([1.0, 0.0, 0.0], (len(chosen), 1))


# Candidates drawn per wanted point before the spacing rejection (at least MIN_POOL).
POOL_PER_POINT = 50
MIN_POOL = 1000
MAX_POOL = 50_000
# Drip points the competition for the rim starved stay as nubs down to this share of
# drips.min_length (a row of frozen pendant drops and short stubs between the long icicles).
NUB_SHARE = 0.4
# A physical storm's icicle hangs at most this share of the free fall below its drip point.
FALL_SHARE = 0.85
# An icicle needs this much room (m) around its drip point, half drips.min_fall below it, in
# ROOM_RAYS level directions (`side_room`): about its base's radius in a moderate storm.
ROOM = 0.01
ROOM_RAYS = 8
# Dropping the dry drip points gives their rim to the rest; these many rounds of dropping and
# re-draining settle every case seen (then whatever is still dry goes too).
MAX_DRY_PASSES = 4



def free_fall(cast, points: np.ndarray, normals: np.ndarray, gravity, floor: float | None = None) -> np.ndarray:
    """``(k,)`` meters a drop falls from each of ``points`` (k, 3) before it lands: on the
    surface that ``cast`` (a `icefarm.spatial.ray_caster`) sees straight below, lifted a
    tenth of a millimetre along ``normals`` (k, 3) off its own face, or on the ground at
    height ``floor`` along -gravity (inf without either)."""
    g = unit(np.asarray(gravity, dtype=np.float64))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    distance, _ = cast(points + tol.ray_lift_m * unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3)),
                       np.tile(g, (len(points), 1)))
    if floor is not None:
        distance = np.minimum(distance, np.maximum(points @ -g - floor, 0.0))
    return distance


def side_room(cast, face_normals: np.ndarray, points: np.ndarray, gravity, depth,
              clearance=ROOM) -> np.ndarray:
    """``(k,) bool``: each of ``points`` (k, 3) has ``clearance`` meters of room around it
    ``depth`` meters below it: level rays from there in `ROOM_RAYS` directions hit nothing
    of the object (``cast``, a `icefarm.spatial.ray_caster` of a mesh whose
    ``face_normals`` (f, 3) these are) within ``clearance``. A drip
    point beside a leg or a wall under its rim has none: its icicle would hang glued to
    the leg (its water runs down the leg instead). A ray that starts inside the object (it
    first meets a face from behind) is not counted. ``depth`` and ``clearance`` (meters) may
    be (k,) arrays."""
    g = unit(np.asarray(gravity, dtype=np.float64))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    e1, e2 = perpendicular_basis(g)
    start = points + np.reshape(depth, (-1, 1)) * g
    room = np.ones(len(points), dtype=bool)
    for angle in np.linspace(0.0, 2.0 * np.pi, ROOM_RAYS, endpoint=False):
        direction = np.cos(angle) * e1 + np.sin(angle) * e2
        distance, face = cast(start, np.tile(direction, (len(points), 1)))
        hit = np.isfinite(distance) & (distance < clearance)
        hit[hit] = face_normals[face[hit]] @ direction < 0  # met from outside
        room &= ~hit
    return room


def _rim_pool(mesh, flux, region, gravity, spacing, count) -> int:
    """Candidates to draw so that dart throwing fills every shedding rim at ``spacing``: `POOL_PER_POINT`
    per point the rims hold (their length over ``spacing``, at most ``count``)."""
    _, _, _, width, _ = rim_half_edges(mesh, flux, region, gravity)
    hold = count if spacing <= 0 else min(count, int(np.ceil(width.sum() / spacing)) + 1)
    return min(MAX_POOL, max(2 * hold, POOL_PER_POINT * hold, MIN_POOL))


@dataclass(frozen=True)
class DripOptions:
    """How stage 2 places its drip points: the ``drips`` parameter group as a job applies it.

    Attributes
    ----------
    count : int
        Drip points wanted (ns); fewer come back when the region cannot hold more at
        ``spacing`` or has fewer vertices.
    drip_limit : float
        dl, degrees from gravity.
    spacing : float
        Least distance between two drip points, in meters (``drips.spacing``).
    distribution : {"water", "area"}
        ``drips.distribution``.
    min_fall : float
        Least free fall below a drip point, in meters (``drips.min_fall``): to the first
        surface of the mesh straight below it or to ``floor``. Where the drop lands sooner
        there is no room for an icicle (it would be a stub cut by what is below); the water
        lands there instead. 0 keeps every point.
    min_water : float
        Least water coefficient of a drip point (meters): where less drips, the drop freezes
        in place as part of the glaze instead of growing an icicle. The pipeline sets it
        from ``drips.min_length`` over the length scale kL. 0 keeps every point.
    floor : float, optional
        Height of the ground along -gravity (a grounded object), meters.
    exclude_boxes : sequence of ((3,), (3,)) corners, meters
        No icicles on faces touching a vertex inside a box.
    exclude_vertices : (n,) bool, optional
        No icicles on faces touching these vertices (a painted mask, the sole).
    """

    count: int
    drip_limit: float
    spacing: float = 0.0
    distribution: str = "area"
    min_fall: float = 0.0
    min_water: float = 0.0
    floor: float | None = None
    exclude_boxes: Sequence = ()
    exclude_vertices: np.ndarray | None = None


@dataclass(frozen=True)
class DripStorm:
    """A physical storm's water off the object (`icefarm.stages.storm`), for `find_drips`.

    Attributes
    ----------
    shed : (n,) float
        The water dripping off at each vertex, m^3. It replaces the water coefficients'
        `drip_flux`: the region is where it sheds, points are drawn by it along the rims (as
        many as the rims hold at ``spacing``, at most ``count``), each point's water is the
        volume its stretch of rim sheds (`catchment_volume`); the icicles compete for the rim
        (`icefarm.stages.rims.compete`) and those a bigger one would fuse with feed it
        (`icefarm.stages.rims.swallow`).
    sizing : icefarm.stages.icicle_size.IcicleSizing, optional
        Icicles' lengths and radii from their water; a drip point's water is then the
        length over ``length_scale`` (kL).
    length_scale : float
        kL, meters (with ``sizing``).
    """

    shed: np.ndarray
    sizing: Any = None
    length_scale: float = 1.0


@dataclass(frozen=True)
class _Rim:
    """Where the water drips off, as the draining of drip points reads it: the region's faces,
    the water shed at each vertex (None: spread by area) and the step along the rims, m."""

    region: np.ndarray
    flux: np.ndarray | None
    step: float


def find_drips(mesh: trimesh.Trimesh, water: np.ndarray, gravity, options: DripOptions,
               rng: np.random.Generator, *, caster=None, storm: DripStorm | None = None) -> DripResult:
    """Stage 2: the drip region and up to ``options.count`` drip points on it.

    ``distribution="area"`` spreads the points area-weighted over the region's faces (the
    paper). ``distribution="water"`` draws them by the water that drips off there
    (`drip_flux`): along the rims of the region where the water leaves the object (lips,
    eaves, spouts, the bottoms of domes), each point's water being what its stretch of the
    rim sheds (`catchment_water`). Either way candidates are drawn at random and kept in
    order when no kept point lies closer than ``spacing`` (dart throwing), so **fewer than
    ``count`` points come back when the region cannot hold more at that spacing** (a rim
    of length L holds about L / spacing). With ``spacing=0`` and ``"area"`` the result is the
    original one for a given generator state. Where no face qualifies (coarse curved
    meshes) the points go on the qualifying edges, length-weighted, or vertices.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface stage 1 ran on, in meters.
    water : (n,) float
        Water coefficients of its vertices.
    gravity : (3,) float
    options : DripOptions
        How many points, where and how far apart.
    rng : numpy.random.Generator
    caster : callable, optional
        A `icefarm.spatial.ray_caster` of ``mesh`` to reuse.
    storm : DripStorm, optional
        A physical storm's shed water and icicle sizing.
    """
    water = np.asarray(water, dtype=np.float64)
    if water.shape != (len(mesh.vertices),):
        raise ValueError(f"water must have one value per vertex ({len(mesh.vertices)}), got {water.shape}")
    o = options
    if not (np.isfinite(o.min_water) and o.min_water >= 0):  # derived (drips.min_length / kL), not a parameter
        raise ValueError(f"min_water must be a non-negative water coefficient, got {o.min_water}")
    if o.min_fall > 0:
        caster = caster or ray_caster(mesh)
    excluded = excluded_vertices(mesh.vertices, o.exclude_boxes)
    if o.exclude_vertices is not None:
        excluded |= np.asarray(o.exclude_vertices, dtype=bool)
    if storm is not None:
        storm = dataclasses.replace(storm, shed=np.asarray(storm.shed, dtype=np.float64))
        if storm.shed.shape != water.shape:
            raise ValueError(f"shed must have one value per vertex ({len(mesh.vertices)}), got {storm.shed.shape}")
    region, flux, pool = _drip_sources(mesh, water, gravity, o, excluded, storm)
    by_water = flux is not None and flux.sum() > 0
    corners, bary, face = _drawn_points(mesh, gravity, o, region, flux if by_water else None, pool, rng, caster,
                                         storm is not None)
    if len(face) == 0 and o.count > 0:
        by_water = False
        corners, bary, face = _transition_drips(mesh, water, gravity, o, excluded, pool, rng, caster)
    positions = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners])
    normals = unit(np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[corners]))
    coefficients = np.einsum("ij,ij->i", bary, water[corners])
    rim = _Rim(region, flux, (o.spacing or float(np.median(mesh.edges_unique_length))) / SAMPLES_PER_SPACING)
    drain = _drainer(mesh, water, gravity, o, rim, storm) if by_water else None
    positions, normals, face, coefficients = _drop_dry(positions, normals, face, coefficients, o.min_water, drain)
    active = None
    if by_water and storm is not None and len(positions):
        keep, coefficients, active = _compete(mesh, gravity, o, rim, storm, positions, normals, rng, caster)
        positions, normals, face, coefficients, active = (positions[keep], normals[keep], face[keep],
                                                          coefficients[keep], active[keep])
    return DripResult(region_faces=region, positions=positions, normals=normals,
                      water=coefficients, faces=face, active=active)


def _drip_sources(mesh, water, gravity, o: DripOptions, excluded, storm):
    """The drip region, the water shed at each vertex that draws the points along its rims
    (None: by area) and how many candidates to draw."""
    if storm is not None:
        region = drip_region(mesh, storm.shed, gravity, o.drip_limit, excluded)
        flux = np.where(np.isin(np.arange(len(storm.shed)), mesh.faces[region]), storm.shed, 0.0)
        return region, flux, _rim_pool(mesh, flux, region, gravity, o.spacing, o.count)
    region = drip_region(mesh, water, gravity, o.drip_limit, excluded)
    count = o.count
    pool = 2 * count if o.spacing == 0 else min(MAX_POOL, max(2 * count, POOL_PER_POINT * count, MIN_POOL))
    flux = drip_flux(mesh, water, gravity, o.drip_limit, region) if o.distribution == "water" else None
    return region, flux, pool


def _drawn_points(mesh, gravity, o: DripOptions, region, flux, pool, rng, caster, physical: bool):
    """Candidates drawn along the rims by ``flux`` (or by area), those buried or without room
    below dropped, the rest thinned to ``o.spacing``: ``(corners (k, 3) int, barycentric
    weights (k, 3), faces (k,))``."""
    if flux is not None:
        face, bary = rim_points(mesh, flux, region, gravity, pool, rng)
    else:
        _, face, bary = sample_faces(mesh, region, pool, rng)
    points = np.einsum("ij,ijk->ik", bary, mesh.vertices[mesh.faces[face]])
    if len(face) and mesh.is_watertight:
        # Faces buried inside another part (a horn through a head) cannot drip.
        lifted = points + tol.offset * float(np.linalg.norm(mesh.extents)) * mesh.face_normals[face]
        free = ~inside(caster or ray_caster(mesh), lifted)
        face, bary, points = face[free], bary[free], points[free]
    if o.min_fall > 0:
        room = free_fall(caster, points, mesh.face_normals[face], gravity, o.floor) >= o.min_fall
        if physical:  # a physical storm's fringe; the relative mode keeps the paper's points
            room[room] = side_room(caster, mesh.face_normals, points[room], gravity, 0.5 * o.min_fall)
        face, bary, points = face[room], bary[room], points[room]
    keep = spaced(points, o.spacing, o.count)
    return mesh.faces[face[keep]], bary[keep], face[keep]


def _transition_drips(mesh, water, gravity, o: DripOptions, excluded, pool, rng, caster):
    """Drip points on the qualifying edges or vertices where no face qualifies
    (`_transition_points`), with room below and spaced: as `_drawn_points` returns them."""
    ok = drip_criterion(mesh.vertex_normals, gravity, o.drip_limit) & ~excluded
    corners, bary = _transition_points(mesh, water, ok, o.count if o.spacing == 0 else pool, rng)
    if o.min_fall > 0:
        at = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners])
        room = free_fall(caster, at, np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[corners]),
                         gravity, o.floor) >= o.min_fall
        corners, bary = corners[room], bary[room]
    keep = spaced(np.einsum("ij,ijk->ik", bary, mesh.vertices[corners]), o.spacing, o.count)
    corners, bary = corners[keep], bary[keep]
    return corners, bary, mesh.vertex_faces[corners[:, 0], 0]


def _drainer(mesh, water, gravity, o: DripOptions, rim: _Rim, storm: DripStorm | None):
    """The water of drip points at ``positions`` (k, 3) drained from their stretches of rim:
    a physical storm's volume (or icicle length over kL), else `catchment_water`."""
    def drained(positions: np.ndarray) -> np.ndarray:
        if storm is not None:
            reach = RIM_REACH * max(o.spacing, rim.step)
            volume = catchment_volume(mesh, rim.flux, rim.region, gravity, positions, rim.step, reach=reach)
            return volume if storm.sizing is None else storm.sizing.length(volume) / storm.length_scale
        return catchment_water(mesh, water, rim.flux, rim.region, gravity, positions, rim.step)

    return drained


def _drop_dry(positions, normals, face, coefficients, min_water, drain):
    """The drip points with at least ``min_water``; with ``drain`` (`_drainer`) the rest drain
    the dropped points' stretches of rim too, over up to `MAX_DRY_PASSES` rounds."""
    if drain is not None:
        coefficients = drain(positions)
    for _ in range(MAX_DRY_PASSES):
        wet = coefficients >= min_water
        if wet.all():
            break
        positions, normals, face, coefficients = positions[wet], normals[wet], face[wet], coefficients[wet]
        if drain is not None and len(positions):
            coefficients = drain(positions)
    wet = coefficients >= min_water
    return positions[wet], normals[wet], face[wet], coefficients[wet]


def _compete(mesh, gravity, o: DripOptions, rim: _Rim, storm: DripStorm, positions, normals, rng, caster):
    """A physical storm's icicles compete for the rim: ``(kept (k,) bool, water (k,),
    active (k,))``.

    Only now do the icicles compete for the rim: those it starves stay short, as nubs
    (frozen pendant drops) down to `NUB_SHARE` of drips.min_length; shorter ones freeze
    into the glaze, their water dripping off the rim."""
    sizing, kl = storm.sizing, storm.length_scale
    reach = RIM_REACH * max(o.spacing, rim.step)
    volume = catchment_volume(mesh, rim.flux, rim.region, gravity, positions, rim.step, reach=reach)
    volume, active = compete(volume, positions, rng, o.spacing)
    # half of them had the storm's whole cold, the others less (a later start, shelter)
    exposure = np.minimum(1.0, rng.lognormal(0.0, HEAT_SPREAD, len(volume)))
    kept = np.ones(len(volume), dtype=bool)
    if sizing is not None:
        volume, active, kept = swallow(volume, active, positions, sizing, gravity, exposure=exposure)
        if o.min_fall > 0 and kept.any():  # an icicle that would touch a wall below its rim runs down it
            length = sizing.length(volume[kept], active[kept], exposure[kept])
            depth = 0.5 * length
            clear = sizing.radius(length, active[kept], depth) + FUSE_MARGIN
            kept[kept] = side_room(caster, mesh.face_normals, positions[kept], gravity, depth, clear)
    coefficients = volume if sizing is None else sizing.length(volume, active, exposure) / kl
    if sizing is not None and o.min_fall > 0:
        # An icicle stops short of what lies below it (the water then drips onto it): grown
        # down to it, the icicle would be cut there and thicken into a pillar (the fountain's
        # winners, down to its lower bowl; the bench's, down to the ground).
        fall = free_fall(caster, positions, normals, gravity, o.floor)
        coefficients = np.minimum(coefficients, FALL_SHARE * fall / kl)
    return kept & (coefficients >= NUB_SHARE * o.min_water), coefficients, active
