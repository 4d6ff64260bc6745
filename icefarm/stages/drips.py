"""Stage 2 (paper 4.2): the drip region and the drip points on it.

The paper spreads the drip points uniformly over the drip region (``distribution: area``).
Real water leaves a surface where it first meets one it cannot cling to, so by default
(``distribution: water``) the points go where the water drips off: each vertex's water
runs down its walk (Algorithm 1's chains) into the region and drips in proportion to how
far the region's faces there turn towards gravity (`drip_flux`). A sharp lip or an eave's
edge sheds nearly all of it; a smooth dome sheds it evenly over its area (as the paper);
what is left drips at the region's lowest points. Points never lie closer than
``spacing`` (icicles settle 2.3 to 2.5 cm apart), and each icicle's water is the water
its stretch of the rim sheds (`catchment_water`), so icicles that drain more grow longer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..geometry import inside, ray_caster, sample_faces, unit
from .water import steepest_neighbours


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
    growth : (k,) float or None
        A physical storm's growth ratio of each drip point's icicle (`icefarm.stages.storm.
        growth_ratios`); None: ``surface.growth_ratio``.
    """

    region_faces: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    water: np.ndarray
    faces: np.ndarray
    growth: np.ndarray | None = None


def drip_criterion(normals: np.ndarray, gravity: np.ndarray, drip_limit: float) -> np.ndarray:
    """``(n,) bool``: each unit normal ``(n, 3)`` lies within ``drip_limit`` degrees of gravity."""
    return normals @ unit(gravity) >= np.cos(np.radians(drip_limit))


class Box(NamedTuple):
    """An axis-aligned box where no icicle may hang (a manifest's ``exclude``, ``--exclude``):
    its lowest and highest corners, in meters, in the prepared object's frame. A pair, so
    ``lo, hi = box`` and plain ``((lo), (hi))`` pairs work alike."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


def excluded_vertices(vertices: np.ndarray, boxes=()) -> np.ndarray:
    """``(n,) bool``: vertices inside any `Box` (or ``((xmin, ymin, zmin), (xmax, ymax, zmax))``)."""
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


DISTRIBUTIONS = ("water", "area")
# Candidates drawn per wanted point before the spacing rejection (at least MIN_POOL).
POOL_PER_POINT = 50
MIN_POOL = 1000
MAX_POOL = 50_000
# Below this length of the downhill direction (a surface within ~6 degrees of level) the
# water has no direction to cross a rim: every edge there counts in full.
LEVEL = 0.1
# Deterministic samples of the shed water per spacing along the rim, for the catchments.
SAMPLES_PER_SPACING = 4
MAX_FLUX_SAMPLES = 200_000
# Dropping the dry drip points gives their rim to the rest; these many rounds of dropping and
# re-draining settle every case seen (then whatever is still dry goes too).
MAX_DRY_PASSES = 4
# An icicle's water grows with the stretch of rim it drains raised to this power: the order
# stays (more water, longer icicle) while the spread shows. Along an evenly wet rim (a
# fountain's lip) the stretches vary only with the gaps between icicles (32 on a 1.9 m lip
# at 2.5 cm spacing: a coefficient of variation of 0.35, under 0.27 one time in twenty);
# real icicles along a rim vary more, as one fed more water widens and draws in more of the
# film beside it. 1.5 gives 0.4 to 0.7 there.
WATER_CONTRAST = 1.5
# An icicle drains at most this many times the water of its neighbours' median stretch
# (one icicle alone on a long rim would otherwise take all of it).
MAX_SHARE = 3.0
# Icicles an icicle's stretch of rim is compared with.
NEIGHBOURS = 6
# Under a physical storm a drip point drains the rim up to this many spacings away (farther
# shed water drips off with no icicle under it): where too little drips for an icicle
# (drips.min_length) the neighbours within reach take it.
RIM_REACH = 2.0


def _chain_max(parent: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``(n,)``: the largest of ``values`` along each vertex's chain of parents, itself included."""
    acc = np.array(values, dtype=np.float64, copy=True)
    ptr = np.asarray(parent, dtype=np.int64).copy()
    while True:
        acc = np.maximum(acc, acc[ptr])
        nxt = ptr[ptr]
        if np.array_equal(nxt, ptr):
            return acc
        ptr = nxt


def drip_flux(mesh: trimesh.Trimesh, water: np.ndarray, gravity, drip_limit: float,
              region: np.ndarray) -> np.ndarray:
    """Water that drips off at each vertex, in meters of water coefficient.

    Each vertex's water arrives down its upward walk (Algorithm 1's chain, followed the
    other way). A vertex's *tilt* is how far its steepest region face turns towards
    gravity, from 0 at the drip limit to 1 facing straight down. Water clings while the
    surface keeps its tilt and sheds as the tilt rises: arriving at a tilt ``t`` after a
    walk whose tilt never exceeded ``m``, the share ``t - m`` of it drips there (so
    ``1 - max tilt`` is still flowing, whatever the mesh resolution: a smooth dome sheds
    evenly over its height, hence its area, as the paper's uniform spread; a sharp lip or
    an eave's edge sheds most of it at once). At a region vertex where the downward walk
    ends (the bottom of a dome, an eave's lower edge) all that is left drips. Water that
    walks out of the region lower down (a bowl's underside into its column) runs on.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    water : (n,) float
        Water coefficients.
    gravity : (3,) float
    drip_limit : float
        dl, degrees.
    region : (m,) int
        Faces of the drip region (`drip_region`).

    Returns
    -------
    (n,) float
        ``water * share`` per vertex; 0 off the region.
    """
    n = len(mesh.vertices)
    if len(region) == 0:
        return np.zeros(n)
    g = unit(gravity)
    cos_limit = np.cos(np.radians(drip_limit))
    face_tilt = np.clip((mesh.face_normals[region] @ g - cos_limit) / (1.0 - cos_limit), 0.0, 1.0)
    tilt = np.zeros(n)
    np.maximum.at(tilt, mesh.faces[region].ravel(), np.repeat(face_tilt, 3))
    (up, _, _), (down, _, _) = steepest_neighbours(mesh, g)
    own = np.arange(n)
    above = np.where(up != own, _chain_max(up, tilt)[up], 0.0)
    share = np.maximum(0.0, tilt - above)
    end = (down == own) & (tilt > 0)
    share[end] = 1.0 - above[end]
    return np.asarray(water, dtype=np.float64) * share


def _rim_half_edges(mesh: trimesh.Trimesh, flux: np.ndarray, region: np.ndarray, gravity):
    """Half-edges of the region's faces that shed water, and their weights.

    The water ``flux[v]`` shed at a vertex is spread over the half of each region edge
    next to it that leads to another shedding vertex (along the rim; every edge when it
    sheds alone), in proportion to the edge's length across the downhill direction at
    ``v`` (an eave's edge catches the water running down to it; an edge running downhill
    does not).

    Returns
    -------
    face, corner_v, corner_u : (h,) int
        Region face of each half-edge and the corners (0-2) of its near and far ends.
    width : (h,) float
        Rim it stands for: its length across the downhill direction, in meters.
    weight : (h,) float
        Water shed along it, in meters of water times meters of rim.
    """
    faces = mesh.faces[region]
    pairs = [(a, b) for a in range(3) for b in range(3) if a != b]
    corner_v = np.repeat([a for a, _ in pairs], len(region))
    corner_u = np.repeat([b for _, b in pairs], len(region))
    face = np.tile(region, len(pairs))
    local = np.tile(np.arange(len(region)), len(pairs))
    v, u = faces[local, corner_v], faces[local, corner_u]
    keep = flux[v] > 0
    # A vertex on a rim sheds along the rim (towards neighbours that shed too); one alone
    # (the bottom of a dome) all around.
    along_rim = np.zeros(len(mesh.vertices), dtype=bool)
    along_rim[v[keep & (flux[u] > 0)]] = True
    keep &= (flux[u] > 0) | ~along_rim[v]
    face, corner_v, corner_u, v, u = face[keep], corner_v[keep], corner_u[keep], v[keep], u[keep]
    if len(v) == 0:
        return face, corner_v, corner_u, np.zeros(0), np.zeros(0)
    # An edge shared by two region faces is split between them.
    _, inverse, counts = np.unique(v * len(mesh.vertices) + u, return_inverse=True, return_counts=True)
    vec = mesh.vertices[u] - mesh.vertices[v]
    length = np.linalg.norm(vec, axis=1)
    g = unit(gravity)
    normal = mesh.vertex_normals[v]
    downhill = g - (normal @ g)[:, None] * normal
    steep = np.linalg.norm(downhill, axis=1)
    along = np.einsum("ij,ij->i", unit(vec), unit(downhill))
    across = np.where(steep > LEVEL, np.sqrt(np.clip(1.0 - along ** 2, 0.0, 1.0)), 1.0)
    width = 0.5 * length * across / counts[inverse]
    return face, corner_v, corner_u, width, flux[v] * width


def _edge_bary(corner_v: np.ndarray, corner_u: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``(k, 3)`` barycentric coordinates ``tau`` of the way from corner ``v`` to corner ``u``."""
    bary = np.zeros((len(tau), 3))
    rows = np.arange(len(tau))
    bary[rows, corner_v] = 1.0 - tau
    bary[rows, corner_u] = tau
    return bary


def _rim_points(mesh, flux, region, gravity, count, rng):
    """``count`` random points where the water drips, drawn by the water shed there."""
    face, cv, cu, _, weight = _rim_half_edges(mesh, flux, region, gravity)
    if count <= 0 or weight.sum() <= 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    pick = rng.choice(len(weight), size=count, p=weight / weight.sum())
    return face[pick], _edge_bary(cv[pick], cu[pick], 0.5 * rng.random(count))


def free_fall(cast, points: np.ndarray, normals: np.ndarray, gravity, floor: float | None = None) -> np.ndarray:
    """``(k,)`` meters a drop falls from each of ``points`` (k, 3) before it lands: on the
    surface that ``cast`` (a `icefarm.geometry.ray_caster`) sees straight below, lifted a
    tenth of a millimetre along ``normals`` (k, 3) off its own face, or on the ground at
    height ``floor`` along -gravity (inf without either)."""
    g = unit(np.asarray(gravity, dtype=np.float64))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    distance, _ = cast(points + 1e-4 * unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3)),
                       np.tile(g, (len(points), 1)))
    if floor is not None:
        distance = np.minimum(distance, np.maximum(points @ -g - floor, 0.0))
    return distance


def _spaced(points: np.ndarray, spacing: float, count: int) -> np.ndarray:
    """Indices of the first points, in order, that lie ``spacing`` or more from every one kept
    before them (dart throwing), at most ``count``.

    Kept points are binned in cells ``spacing`` wide, so each candidate is compared with the
    few kept in the 27 cells around it: linear in the candidates (50,000 along a long rim),
    where comparing with every kept point grew with their product."""
    if spacing <= 0:
        return np.arange(min(count, len(points)))
    points = np.asarray(points, dtype=np.float64)
    cells = np.floor(points / spacing).astype(np.int64).tolist()
    coords = points.tolist()
    grid: dict[tuple, list] = {}
    chosen: list[int] = []
    limit = spacing * spacing
    around = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    for i, (cell, p) in enumerate(zip(cells, coords)):
        if len(chosen) == count:
            break
        x, y, z = p
        cx, cy, cz = cell
        close = False
        for a, b, c in around:
            for q in grid.get((cx + a, cy + b, cz + c), ()):
                if (q[0] - x) ** 2 + (q[1] - y) ** 2 + (q[2] - z) ** 2 < limit:
                    close = True
                    break
            if close:
                break
        if close:
            continue
        grid.setdefault((cx, cy, cz), []).append(p)
        chosen.append(i)
    return np.asarray(chosen, dtype=np.int64)


def catchment_water(mesh: trimesh.Trimesh, water: np.ndarray, flux: np.ndarray, region: np.ndarray,
                    gravity, positions: np.ndarray, step: float) -> np.ndarray:
    """Each icicle's water: the water of the stretch of rim it drains.

    The rim where water drips (`drip_flux`, spread along its edges as in
    `_rim_half_edges`) is sampled every ``step`` meters and each sample goes to the nearest
    drip point: its catchment. Icicle ``i`` gets the mean water coefficient along its
    catchment (the paper's water, so a wetter rim grows longer icicles) times the
    catchment's width over the median width of its `NEIGHBOURS` nearest icicles and its
    own, raised to `WATER_CONTRAST` (at most `MAX_SHARE`): an icicle alone on a long
    stretch of rim drains more of it and grows longer than its neighbours, and one
    crowded by them shorter. (Wetter rims draw more points, so their stretches are
    shorter: comparing with the neighbours, not all icicles, keeps their extra water.)

    Parameters
    ----------
    water : (n,) float
        Water coefficients of the vertices.
    flux : (n,) float
        `drip_flux` of the vertices.
    positions : (k, 3) float
        Drip points.
    step : float
        Sampling step along the rim, in meters.

    Returns
    -------
    (k,) float
        Meters of water coefficient per drip point.
    """
    face, cv, cu, width, _ = _rim_half_edges(mesh, flux, region, gravity)
    if len(positions) == 0 or width.sum() <= 0:
        return np.zeros(len(positions))
    samples, h, bary, corners, pieces = _rim_samples(mesh, face, cv, cu, step)
    wet = np.einsum("ij,ij->i", bary, np.asarray(water, dtype=np.float64)[corners[h]])
    tree = cKDTree(positions)
    _, nearest = tree.query(samples)
    share = width[h] / pieces[h]
    drained = np.bincount(nearest, weights=share, minlength=len(positions))
    coefficient = np.bincount(nearest, weights=share * wet, minlength=len(positions)) / np.maximum(drained, 1e-300)
    _, neighbours = tree.query(positions, k=min(NEIGHBOURS + 1, len(positions)))
    typical = np.median(drained[neighbours.reshape(len(positions), -1)], axis=1)
    ratio = np.divide(drained, typical, out=np.ones(len(positions)), where=typical > 0)
    return coefficient * np.minimum(ratio ** WATER_CONTRAST, MAX_SHARE)


def _rim_samples(mesh, face, cv, cu, step):
    """Deterministic samples every ``step`` meters along the shedding half-edges.

    Returns
    -------
    samples : (s, 3) float
    h : (s,) int
        Half-edge of each sample.
    bary : (s, 3) float
        Its barycentric coordinates in the half-edge's face.
    corners : (e, 3) int
        Vertices of each half-edge's face.
    pieces : (e,) int
        Samples per half-edge.
    """
    corners = mesh.faces[face]
    rows = np.arange(len(face))
    half = 0.5 * np.linalg.norm(mesh.vertices[corners[rows, cu]] - mesh.vertices[corners[rows, cv]], axis=1)
    step = max(step, float(half.sum()) / MAX_FLUX_SAMPLES)
    pieces = np.maximum(1, np.ceil(half / step)).astype(np.int64)
    h = np.repeat(rows, pieces)
    i = np.arange(len(h)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    bary = _edge_bary(cv[h], cu[h], 0.5 * (i + 0.5) / pieces[h])
    samples = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners[h]])
    return samples, h, bary, corners, pieces


def catchment_volume(mesh: trimesh.Trimesh, shed: np.ndarray, region: np.ndarray, gravity,
                     positions: np.ndarray, step: float, reach: float) -> np.ndarray:
    """Each drip point's water under a physical storm: what its stretch of rim sheds, m^3.

    The water ``shed[v]`` at a vertex is spread along the shedding half-edges next to it in
    proportion to their width across the downhill direction (`_rim_half_edges`), sampled
    every ``step`` meters; each sample goes to the nearest drip point within ``reach``
    meters. Water shed farther from every drip point drips off with no icicle under it.

    Parameters
    ----------
    shed : (n,) float
        Water dripping off at each vertex, m^3 (`icefarm.stages.storm.StormResult.shed`).
    positions : (k, 3) float
        Drip points.
    step, reach : float
        Meters.

    Returns
    -------
    (k,) float
        m^3 of water per drip point (their sum is at most ``shed.sum()``).
    """
    face, cv, cu, width, _ = _rim_half_edges(mesh, shed, region, gravity)
    if len(positions) == 0 or width.sum() <= 0:
        return np.zeros(len(positions))
    near_v = mesh.faces[face, cv]
    around = np.bincount(near_v, weights=width, minlength=len(mesh.vertices))
    per_edge = np.asarray(shed, dtype=np.float64)[near_v] * width / np.maximum(around[near_v], 1e-300)
    samples, h, _, _, pieces = _rim_samples(mesh, face, cv, cu, step)
    distance, nearest = cKDTree(positions).query(samples, distance_upper_bound=reach)
    close = np.isfinite(distance)
    return np.bincount(nearest[close], weights=(per_edge[h] / pieces[h])[close], minlength=len(positions))



def compete(volume: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """``(k,)`` each drip point's water after its neighbours compete for the film, m^3.

    An icicle fed more than its `NEIGHBOURS` widens and draws in more of the film beside it:
    its water over their median is raised to `WATER_CONTRAST` (at most `MAX_SHARE`), then all
    are scaled back to the same total, so no water is made or lost. Along an evenly wet rim
    the stretches differ only by the gaps dart throwing leaves (a table's 106 icicles all came
    out 20-24 cm); this gives the spread of lengths real rims show."""
    volume = np.asarray(volume, dtype=np.float64)
    if len(volume) < 2 or volume.sum() <= 0:
        return volume
    _, neighbours = cKDTree(positions).query(positions, k=min(NEIGHBOURS + 1, len(positions)))
    typical = np.median(volume[neighbours.reshape(len(volume), -1)], axis=1)
    ratio = np.divide(volume, typical, out=np.ones(len(volume)), where=typical > 0)
    drawn = volume * np.minimum(ratio ** (WATER_CONTRAST - 1.0), MAX_SHARE)
    return drawn * (volume.sum() / drawn.sum()) if drawn.sum() > 0 else volume

def _rim_pool(mesh, flux, region, gravity, spacing, count) -> int:
    """Candidates to draw so that dart throwing fills every shedding rim at ``spacing``: `POOL_PER_POINT`
    per point the rims hold (their length over ``spacing``, at most ``count``)."""
    _, _, _, width, _ = _rim_half_edges(mesh, flux, region, gravity)
    hold = count if spacing <= 0 else min(count, int(np.ceil(width.sum() / spacing)) + 1)
    return min(MAX_POOL, max(2 * hold, POOL_PER_POINT * hold, MIN_POOL))


def find_drips(mesh: trimesh.Trimesh, water: np.ndarray, gravity, count: int, drip_limit: float,
               rng: np.random.Generator, exclude_boxes=(),
               exclude_vertices: np.ndarray | None = None, caster=None,
               spacing: float = 0.0, distribution: str = "area", min_fall: float = 0.0,
               floor: float | None = None, min_water: float = 0.0, shed: np.ndarray | None = None,
               to_water=None) -> DripResult:
    """Stage 2: the drip region and up to ``count`` drip points on it.

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
    count : int
        Drip points wanted (ns); fewer come back when the region cannot hold more at
        ``spacing`` or has fewer vertices.
    drip_limit : float
        dl, degrees from gravity.
    rng : numpy.random.Generator
    exclude_boxes : sequence of ((3,), (3,)) corners, meters
        No icicles on faces touching a vertex inside a box.
    exclude_vertices : (n,) bool, optional
        No icicles on faces touching these vertices (a painted mask).
    caster : callable, optional
        A `icefarm.geometry.ray_caster` of ``mesh`` to reuse.
    spacing : float
        Least distance between two drip points, in meters (``drips.spacing``).
    distribution : {"water", "area"}
        ``drips.distribution``.
    min_fall : float
        Least free fall below a drip point, in meters (``drips.min_fall``): to the first
        surface of ``mesh`` straight below it or to ``floor``. Where the drop lands sooner
        there is no room for an icicle (it would be a stub cut by what is below); the water
        lands there instead. 0 keeps every point.
    floor : float, optional
        Height of the ground along -gravity (a grounded object), meters.
    min_water : float
        Least water coefficient of a drip point (meters): where less drips, the drop freezes
        in place as part of the glaze instead of growing an icicle. The pipeline sets it
        from ``drips.min_length`` over the length scale kL. 0 keeps every point.
    shed : (n,) float, optional
        A physical storm (`icefarm.stages.storm`): the water dripping off at each vertex,
        m^3. It replaces the water coefficients' `drip_flux`: the region is where it sheds,
        points are drawn by it along the rims (as many as the rims hold at ``spacing``, at
        most ``count``), each point's water is the volume its stretch of rim sheds
        (`catchment_volume`), turned into a water coefficient by ``to_water``.
    to_water : callable, optional
        ``(k,) m^3 -> (k,)`` meters of water coefficient (with ``shed``); identity if None.
    """
    water = np.asarray(water, dtype=np.float64)
    if water.shape != (len(mesh.vertices),):
        raise ValueError(f"water must have one value per vertex ({len(mesh.vertices)}), got {water.shape}")
    if not 0 < drip_limit < 90:
        raise ValueError(f"drip_limit must lie in ]0, 90[ degrees, got {drip_limit}")
    if not (np.isfinite(spacing) and spacing >= 0):
        raise ValueError(f"spacing must be a non-negative number of meters, got {spacing}")
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution must be one of {', '.join(DISTRIBUTIONS)}, got {distribution!r}")
    if not (np.isfinite(min_water) and min_water >= 0):
        raise ValueError(f"min_water must be a non-negative water coefficient, got {min_water}")
    if not (np.isfinite(min_fall) and min_fall >= 0):
        raise ValueError(f"min_fall must be a non-negative number of meters, got {min_fall}")
    if min_fall > 0:
        caster = caster or ray_caster(mesh)
    excluded = excluded_vertices(mesh.vertices, exclude_boxes)
    if exclude_vertices is not None:
        excluded |= np.asarray(exclude_vertices, dtype=bool)
    if shed is not None:
        shed = np.asarray(shed, dtype=np.float64)
        if shed.shape != water.shape:
            raise ValueError(f"shed must have one value per vertex ({len(mesh.vertices)}), got {shed.shape}")
        region = drip_region(mesh, shed, gravity, drip_limit, excluded)
        flux = np.where(np.isin(np.arange(len(shed)), mesh.faces[region]), shed, 0.0)
        pool = _rim_pool(mesh, flux, region, gravity, spacing, count)
    else:
        region = drip_region(mesh, water, gravity, drip_limit, excluded)
        pool = 2 * count if spacing == 0 else min(MAX_POOL, max(2 * count, POOL_PER_POINT * count, MIN_POOL))
        flux = drip_flux(mesh, water, gravity, drip_limit, region) if distribution == "water" else None
    by_water = flux is not None and flux.sum() > 0
    if by_water:
        face, bary = _rim_points(mesh, flux, region, gravity, pool, rng)
    else:
        _, face, bary = sample_faces(mesh, region, pool, rng)
    points = np.einsum("ij,ijk->ik", bary, mesh.vertices[mesh.faces[face]])
    if len(face) and mesh.is_watertight:
        # Faces buried inside another part (a horn through a head) cannot drip.
        lifted = points + 1e-4 * float(np.linalg.norm(mesh.extents)) * mesh.face_normals[face]
        free = ~inside(caster or ray_caster(mesh), lifted)
        face, bary, points = face[free], bary[free], points[free]
    if min_fall > 0:
        room = free_fall(caster, points, mesh.face_normals[face], gravity, floor) >= min_fall
        face, bary, points = face[room], bary[room], points[room]
    keep = _spaced(points, spacing, count)
    face, bary = face[keep], bary[keep]
    corners = mesh.faces[face]
    if len(face) == 0 and count > 0:
        by_water = False
        ok = drip_criterion(mesh.vertex_normals, gravity, drip_limit) & ~excluded
        corners, bary = _transition_points(mesh, water, ok, count if spacing == 0 else pool, rng)
        if min_fall > 0:
            at = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners])
            room = free_fall(caster, at, np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[corners]),
                             gravity, floor) >= min_fall
            corners, bary = corners[room], bary[room]
        keep = _spaced(np.einsum("ij,ijk->ik", bary, mesh.vertices[corners]), spacing, count)
        corners, bary = corners[keep], bary[keep]
        face = mesh.vertex_faces[corners[:, 0], 0]
    positions = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners])
    normals = unit(np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[corners]))
    coefficients = np.einsum("ij,ij->i", bary, water[corners])
    step = (spacing or float(np.median(mesh.edges_unique_length))) / SAMPLES_PER_SPACING

    def drained(positions: np.ndarray, final: bool = False) -> np.ndarray:
        if shed is not None:
            volume = catchment_volume(mesh, flux, region, gravity, positions, step, reach=RIM_REACH * max(spacing, step))
            if final:  # after the dry points are gone: competing then would starve the weak ones in turn
                volume = compete(volume, positions)
            return volume if to_water is None else np.asarray(to_water(volume), dtype=np.float64)
        return catchment_water(mesh, water, flux, region, gravity, positions, step)

    if by_water:
        coefficients = drained(positions)
    for _ in range(MAX_DRY_PASSES):  # the rest drain the dry points' stretches of rim too
        wet = coefficients >= min_water
        if wet.all():
            break
        positions, normals, face, coefficients = positions[wet], normals[wet], face[wet], coefficients[wet]
        if by_water and len(positions):
            coefficients = drained(positions)
    wet = coefficients >= min_water
    positions, normals, face, coefficients = positions[wet], normals[wet], face[wet], coefficients[wet]
    if by_water and shed is not None and len(positions):
        coefficients = drained(positions, final=True)
    return DripResult(region_faces=region, positions=positions, normals=normals,
                      water=coefficients, faces=face)
