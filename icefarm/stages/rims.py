"""The rims where water drips: how much each stretch sheds, points drawn along them, and
each drip point's share (stage 2's water bookkeeping, `icefarm.stages.drips`).

Relative mode: each vertex's water coefficient runs down its walk and drips as the surface
turns towards gravity (`drip_flux`); an icicle gets the mean coefficient of its stretch of
rim, contrasted with its neighbours' (`catchment_water`). Physical storm: the water shed at
each vertex (`icefarm.stages.storm`) is spread along the rim and summed per drip point
(`catchment_volume`), then the points compete for it with the total kept (`compete`).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..geometry import ragged_arange, unit
from .water import steepest_neighbours

# Below this length of the downhill direction (a surface within ~6 degrees of level) the
# water has no direction to cross a rim: every edge there counts in full.
LEVEL = 0.1
# Deterministic samples of the shed water per spacing along the rim, for the catchments.
SAMPLES_PER_SPACING = 4
MAX_FLUX_SAMPLES = 200_000
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
# Icicles along a rim compete for its film (`compete`): rounds of the storm, how far (in
# drip spacings) an icicle draws water from, the Gaussian scale of its pull, how its pull
# grows with its ice, and how much the first drops differ (log-normal sigma). An icicle fed
# less than ACTIVE_FEED of a typical stretch's water in a round did not grow in it.
CAPTURE_ROUNDS = 24
CAPTURE_REACH = 4.0
CAPTURE_SCALE = 3.0
CAPTURE_POWER = 3.0
NUCLEUS_SPREAD = 0.5
# Each icicle's share of the storm's cold varies: half of them have it all, the others less
# (their drip started a night later, they hang sheltered from the wind or the sky): a factor
# min(1, log-normal of this sigma) on its heat budget, so that the icicles the cold limits are
# not all one length (a meltwater eave's winners would hang as an even comb). Chosen.
HEAT_SPREAD = 0.4
ACTIVE_FEED = 0.25
# Icicles whose surfaces come closer than this (m) at half the shorter one's length fuse in
# the metaball field (`swallow`); the passes settle the few that grew into a neighbour.
FUSE_MARGIN = 0.010
SWALLOW_PASSES = 3
# Icicles this long (m) and more carry side branches often enough to count them (`swallow`).
BRANCHY = 0.15


def chain_max(parent: np.ndarray, values: np.ndarray) -> np.ndarray:
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
    above = np.where(up != own, chain_max(up, tilt)[up], 0.0)
    share = np.maximum(0.0, tilt - above)
    end = (down == own) & (tilt > 0)
    share[end] = 1.0 - above[end]
    return np.asarray(water, dtype=np.float64) * share


def rim_half_edges(mesh: trimesh.Trimesh, flux: np.ndarray, region: np.ndarray, gravity):
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


def edge_bary(corner_v: np.ndarray, corner_u: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``(k, 3)`` barycentric coordinates ``tau`` of the way from corner ``v`` to corner ``u``."""
    bary = np.zeros((len(tau), 3))
    rows = np.arange(len(tau))
    bary[rows, corner_v] = 1.0 - tau
    bary[rows, corner_u] = tau
    return bary


def rim_points(mesh, flux, region, gravity, count, rng):
    """``count`` random points where the water drips, drawn by the water shed there."""
    face, cv, cu, _, weight = rim_half_edges(mesh, flux, region, gravity)
    if count <= 0 or weight.sum() <= 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    pick = rng.choice(len(weight), size=count, p=weight / weight.sum())
    return face[pick], edge_bary(cv[pick], cu[pick], 0.5 * rng.random(count))


def catchment_water(mesh: trimesh.Trimesh, water: np.ndarray, flux: np.ndarray, region: np.ndarray,
                    gravity, positions: np.ndarray, step: float) -> np.ndarray:
    """Each icicle's water: the water of the stretch of rim it drains.

    The rim where water drips (`drip_flux`, spread along its edges as in
    `rim_half_edges`) is sampled every ``step`` meters and each sample goes to the nearest
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
    face, cv, cu, width, _ = rim_half_edges(mesh, flux, region, gravity)
    if len(positions) == 0 or width.sum() <= 0:
        return np.zeros(len(positions))
    samples, h, bary, corners, pieces = rim_samples(mesh, face, cv, cu, step)
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


def rim_samples(mesh, face, cv, cu, step):
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
    i = ragged_arange(pieces)
    bary = edge_bary(cv[h], cu[h], 0.5 * (i + 0.5) / pieces[h])
    samples = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners[h]])
    return samples, h, bary, corners, pieces


def catchment_volume(mesh: trimesh.Trimesh, shed: np.ndarray, region: np.ndarray, gravity,
                     positions: np.ndarray, step: float, reach: float) -> np.ndarray:
    """Each drip point's water under a physical storm: what its stretch of rim sheds, m^3.

    The water ``shed[v]`` at a vertex is spread along the shedding half-edges next to it in
    proportion to their width across the downhill direction (`rim_half_edges`), sampled
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
    face, cv, cu, width, _ = rim_half_edges(mesh, shed, region, gravity)
    if len(positions) == 0 or width.sum() <= 0:
        return np.zeros(len(positions))
    near_v = mesh.faces[face, cv]
    around = np.bincount(near_v, weights=width, minlength=len(mesh.vertices))
    per_edge = np.asarray(shed, dtype=np.float64)[near_v] * width / np.maximum(around[near_v], 1e-300)
    samples, h, _, _, pieces = rim_samples(mesh, face, cv, cu, step)
    distance, nearest = cKDTree(positions).query(samples, distance_upper_bound=reach)
    close = np.isfinite(distance)
    return np.bincount(nearest[close], weights=(per_edge[h] / pieces[h])[close], minlength=len(positions))



def compete(volume: np.ndarray, positions: np.ndarray, rng: np.random.Generator,
            spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Each drip point's water after the icicles along the rim compete for the film, m^3.

    Water running along a rim is drawn into the pendant drop of an icicle, and a bigger
    icicle draws it from farther: its drop hangs lower and its base widens over the rim
    (Makkonen 1988; Maeno et al. 1994 saw a few icicles of an eave take most of its water).
    The storm is grown in `CAPTURE_ROUNDS` steps. In each, every drip point's stretch of rim
    sheds its share of the round, and the icicles within `CAPTURE_REACH` spacings take it in
    proportion to their ice so far raised to `CAPTURE_POWER`, times a Gaussian of the
    distance (`CAPTURE_SCALE` spacings). The first drops differ by chance (`NUCLEUS_SPREAD`,
    log-normal): that is all a rich-get-richer process needs. A few icicles come to drain
    the rim for several spacings around them and grow long; those between them starve early
    and stay short; no water is made or lost.

    Parameters
    ----------
    volume : (k,) float
        Water each point's own stretch of rim sheds over the storm, m^3 (`catchment_volume`).
    positions : (k, 3) float
        Drip points, meters.
    rng : numpy.random.Generator
    spacing : float
        ``drips.spacing``, meters.

    Returns
    -------
    water : (k,) float
        m^3 each icicle drew (same total as ``volume``).
    active : (k,) float
        Share of the storm each icicle was fed (0 to 1): one that starved early stopped
        thickening then too.
    """
    volume = np.asarray(volume, dtype=np.float64)
    k = len(volume)
    if k < 2 or volume.sum() <= 0 or spacing <= 0:
        return volume, np.ones(k)
    pairs = cKDTree(positions).query_pairs(CAPTURE_REACH * spacing, output_type="ndarray")
    own = np.arange(k)
    sender = np.r_[pairs[:, 0], pairs[:, 1], own]
    taker = np.r_[pairs[:, 1], pairs[:, 0], own]
    distance = np.linalg.norm(positions[sender] - positions[taker], axis=1)
    kernel = np.exp(-(distance / (CAPTURE_SCALE * spacing)) ** 2)
    feed = volume / CAPTURE_ROUNDS
    typical = float(np.median(feed[feed > 0])) if (feed > 0).any() else 0.0
    size = np.maximum(feed, 1e-3 * typical) * rng.lognormal(0.0, NUCLEUS_SPREAD, k)
    water = np.zeros(k)
    active = np.zeros(k)
    for _ in range(CAPTURE_ROUNDS):
        pull = kernel * size[taker] ** CAPTURE_POWER
        total = np.bincount(sender, weights=pull, minlength=k)
        got = np.bincount(taker, weights=feed[sender] * pull / np.maximum(total[sender], 1e-300), minlength=k)
        water += got
        size += got
        active += np.minimum(1.0, got / (ACTIVE_FEED * typical)) if typical > 0 else 1.0
    return water * (volume.sum() / water.sum()), active / CAPTURE_ROUNDS


def swallow(volume: np.ndarray, active: np.ndarray, positions: np.ndarray, sizing, gravity,
            margin: float = FUSE_MARGIN, exposure: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drip points under the flank of a bigger icicle feed it instead of hanging their own.

    From the longest icicle down, each drip point whose icicle would touch a longer one's
    at half its own length (root distance under the two radii there plus ``margin``) is
    taken in: its water runs down the bigger icicle, which grows with it. Real fringes fuse
    near their roots, rarely down their length, and keep gaps between their long icicles.

    Parameters
    ----------
    volume, active : (k,) float
        `compete`'s water, m^3, and share of the storm fed.
    positions : (k, 3) float
        Drip points, meters.
    sizing : icefarm.stages.icicle_size.IcicleSizing
    gravity : (3,) float
        Roots at different heights are compared at the same level.
    margin : float
        Meters the surfaces of two icicles keep apart: the metaball field fuses closer ones.
    exposure : (k,) float, optional
        Each icicle's share of the cold (`IcicleSizing.length`).

    Returns
    -------
    volume, active : (k,) float
        Zero water for the points taken in.
    kept : (k,) bool
    """
    volume = np.array(volume, dtype=np.float64)
    active = np.array(active, dtype=np.float64)
    k = len(volume)
    kept = volume > 0
    if k < 2:
        return volume, active, kept
    length = sizing.length(volume, active, exposure)
    up = -unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    tree = cKDTree(positions)
    widest = float(sizing.radius(length[[int(np.argmax(length))]], active[[int(np.argmax(length))]], [0.0])[0])
    for _ in range(SWALLOW_PASSES):
        changed = False
        for i in np.argsort(-length, kind="stable"):
            if not kept[i]:
                continue
            reach = 2.0 * widest + margin + sizing.branch_reach
            near = np.asarray(tree.query_ball_point(positions[i], reach), dtype=np.int64)
            near = near[kept[near] & (near != i) & (length[near] <= length[i])]
            if len(near) == 0:
                continue
            # compared at the level of the shorter one's half length, level distances apart
            offset = positions[near] - positions[i]
            rise = offset @ up  # how far the shorter one's root lies above this one's
            level = np.linalg.norm(offset - rise[:, None] * up, axis=1)
            depth = 0.5 * length[near]
            gap = (level - sizing.radius(np.full(len(near), length[i]), np.full(len(near), active[i]), depth - rise)
                   - sizing.radius(length[near], active[near], depth))
            # side branches hang up to branch_reach aside of a long trunk, low enough to meet a
            # long neighbour at its half length (a short one's half length is above them)
            fused = near[gap < margin + np.where(length[near] >= BRANCHY, sizing.branch_reach, 0.0)]
            if len(fused) == 0:
                continue
            volume[i] += volume[fused].sum()
            volume[fused] = 0.0
            kept[fused] = False
            length[i] = sizing.length(volume[[i]], active[[i]], None if exposure is None else exposure[[i]])[0]
            length[fused] = 0.0
            widest = max(widest, float(sizing.radius(length[[i]], active[[i]], [0.0])[0]))
            changed = True
        if not changed:
            break
    return volume, active, kept
