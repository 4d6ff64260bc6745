"""Basins on a surface: where water stands before it can flow out, and where a full basin
spills over its rim (``water.pools: overflow``: fountains, gutters).

`spill_levels` floods the surface from its outlets; `overflow_heights` gives the relative
mode's water coefficients what full basins add where they spill; `spill_routes` and
`spill_over` carry a physical storm's pooled water over the rim to the outside, where it
runs on and drips (`icefarm.stages.storm.accrete`).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..geometry import unit
from ..spatial import ray_caster
from ..tol import tol


def spill_levels(heights: np.ndarray, edges: np.ndarray, outlets: np.ndarray) -> np.ndarray:
    """Height to which water stands at each vertex before it can flow out (a priority flood).

    The level of a vertex is the lowest, over paths to an outlet, of the highest vertex on
    the path: a vertex in a basin stands under water up to the basin's lowest rim point;
    any other vertex's level is its own height.

    Parameters
    ----------
    heights : (n,) float
        Height of each vertex against gravity, in meters.
    edges : (k, 2) int
        Edges of the mesh.
    outlets : (n,) bool
        Vertices where water leaves the surface (it drips or runs off there).

    Returns
    -------
    (n,) float
        Level per vertex, in meters (>= its height; inf where no outlet can be reached).
    """
    n = len(heights)
    sources = np.concatenate([edges[:, 0], edges[:, 1]])  # both directions of every edge
    order = np.argsort(sources, kind="stable")
    neighbours = np.concatenate([edges[:, 1], edges[:, 0]])[order].tolist()
    starts = np.searchsorted(sources[order], np.arange(n + 1)).tolist()
    h = heights.tolist()
    level = [float("inf")] * n
    heap = [(h[v], v) for v in np.flatnonzero(outlets).tolist()]
    for lv, v in heap:
        level[v] = lv
    heapq.heapify(heap)
    while heap:  # Dijkstra with max() for + : sequential by nature, so plain Python lists
        lv, v = heapq.heappop(heap)
        if lv > level[v]:
            continue
        for u in neighbours[starts[v]:starts[v + 1]]:
            candidate = lv if lv > h[u] else h[u]
            if candidate < level[u]:
                level[u] = candidate
                heapq.heappush(heap, (candidate, u))
    return np.asarray(level)


@dataclass(frozen=True)
class _Basins:
    """Basins of a surface (`_find_basins`): per vertex its height against gravity, its
    water level (`spill_levels`), whether it stands under water (``wet``) and its basin
    (-1 when dry); per basin its depth (level minus its lowest point); the mesh's unique
    edges and the tolerance within which heights are one level (meters)."""

    heights: np.ndarray
    level: np.ndarray
    wet: np.ndarray
    basin: np.ndarray
    depth: np.ndarray
    edges: np.ndarray
    level_tol: float


def _find_basins(mesh: trimesh.Trimesh, gravity: np.ndarray, caster=None) -> _Basins:
    """`_Basins` of ``mesh``: water leaves the object (outlets) at its lowest points, over
    open edges, and where it drips clear of the object: a downward-facing vertex whose drop
    falls without landing on it again (a drop from a finial's flare lands back in its bowl;
    a drop from a foot's sole does not)."""
    g = unit(gravity)
    heights = -(np.asarray(mesh.vertices) @ g)
    edges = np.asarray(mesh.edges_unique)
    n = len(heights)
    level_tol = tol.level * float(np.ptp(mesh.vertices, axis=0).max()) if n else 0.0
    if len(edges) == 0:
        return _Basins(heights, heights.copy(), np.zeros(n, bool), np.full(n, -1), np.zeros(0), edges, level_tol)
    uses = np.bincount(mesh.edges_unique_inverse, minlength=len(edges))
    outlets = heights <= heights.min() + level_tol
    outlets[edges[uses == 1].ravel()] = True
    normals = np.asarray(mesh.vertex_normals)
    facing_down = np.flatnonzero(normals @ g > 0)
    if len(facing_down):
        cast = caster or ray_caster(mesh)
        lifted = mesh.vertices[facing_down] + tol.hair * float(np.linalg.norm(mesh.extents)) * normals[facing_down]
        outlets[facing_down] |= ~np.isfinite(cast(lifted, np.broadcast_to(g, lifted.shape))[0])
    level = spill_levels(heights, edges, outlets)
    wet = np.isfinite(level) & (level > heights + level_tol)
    inside = wet[edges[:, 0]] & wet[edges[:, 1]]
    graph = coo_matrix((np.ones(inside.sum()), (edges[inside, 0], edges[inside, 1])), shape=(n, n))
    _, basin = connected_components(graph, directed=False)
    basin = np.where(wet, basin, -1)
    count = basin.max() + 1
    bottom, top = np.full(count, np.inf), np.full(count, -np.inf)
    np.minimum.at(bottom, basin[wet], heights[wet])
    np.maximum.at(top, basin[wet], level[wet])  # one level per basin
    return _Basins(heights, level, wet, basin, top - bottom, edges, level_tol)


def _rim_max(b: _Basins, value: np.ndarray) -> np.ndarray:
    """``(n,)`` the largest ``value`` (one per basin, >= 0) of the basins each dry vertex is a
    rim of, 0 off the rims: the dry vertices at their basin's level next to it, and the flat
    rim top around them (where the level runs on across a wide lip)."""
    edges, wet, level, heights = b.edges, b.wet, b.level, b.heights
    out = np.zeros(len(heights))
    for a, c in (edges.T, edges[:, ::-1].T):
        at_rim = wet[a] & ~wet[c] & (np.abs(heights[c] - level[a]) <= b.level_tol)
        np.maximum.at(out, c[at_rim], value[b.basin[a[at_rim]]])
    flat = ~wet[edges[:, 0]] & ~wet[edges[:, 1]] & (np.abs(heights[edges[:, 0]] - heights[edges[:, 1]]) <= b.level_tol)
    a, c = edges[flat, 0], edges[flat, 1]
    while True:  # across the flat rim top
        spread = out.copy()
        np.maximum.at(spread, a, out[c])
        np.maximum.at(spread, c, out[a])
        if np.array_equal(spread, out):
            return out
        out = spread


def overflow_heights(mesh: trimesh.Trimesh, supply: np.ndarray, gravity: np.ndarray,
                     caster=None) -> np.ndarray:
    """What full basins add to the water where they spill: their depth, on their rims.

    A basin is a connected set of vertices under water (`spill_levels`) that rain reaches
    (a supply vertex); see `_find_basins` for where water leaves the object. Filled, it
    spills over its lowest rim points, the dry vertices next to it at its level, and the
    flat rim top around them; each gets the basin's depth (level minus its lowest point):
    the height its water climbed by filling, in Algorithm 1's terms.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface the water flows on, in meters.
    supply : (n,) bool
    gravity : (3,) float
    caster : callable, optional
        A `icefarm.spatial.ray_caster` of ``mesh`` to reuse.

    Returns
    -------
    (n,) float
        Meters to add at each rim vertex; 0 elsewhere.
    """
    b = _find_basins(mesh, gravity, caster)
    n = len(b.heights)
    if not b.wet.any():
        return np.zeros(n)
    rained = np.zeros(len(b.depth), dtype=bool)
    rained[b.basin[b.wet & np.asarray(supply, dtype=bool)]] = True
    return _rim_max(b, np.where(rained, b.depth, 0.0))


@dataclass(frozen=True)
class SpillRoutes:
    """Where each basin's water goes when it is full (`spill_routes`).

    Attributes
    ----------
    basin : (n,) int
        The basin each vertex stands in, -1 when dry.
    target, share : (r,) int, (r,) float
        Vertices just outside the rims that take a full basin's overflow and the share of its
        basin's overflow each takes (a basin's shares add to 1).
    owner : (r,) int
        The basin each route spills from.
    """

    basin: np.ndarray
    target: np.ndarray
    share: np.ndarray
    owner: np.ndarray


def spill_routes(mesh: trimesh.Trimesh, gravity, caster=None) -> SpillRoutes:
    """Where full basins of ``mesh`` spill: over every rim point at the basin's level (a
    level lip spills all round, a notch alone where there is one) to its dry neighbours
    below the lip that belong to no part of that basin or its rim, evenly by route.

    Water going there never comes back: a dry vertex under the level is off the basin's
    flood (its own level is its height), so every way down from it leads away.
    """
    b = _find_basins(mesh, gravity, caster)
    if not b.wet.any():
        empty = np.zeros(0, dtype=np.int64)
        return SpillRoutes(b.basin, empty, np.zeros(0), empty)
    # each rim vertex spills the deepest basin it bounds: rank them by depth, 1 the shallowest
    by_depth = np.argsort(b.depth, kind="stable")
    rank = np.empty(len(by_depth))
    rank[by_depth] = np.arange(1, len(by_depth) + 1)
    top = _rim_max(b, rank).astype(np.int64)
    rim = np.where(top > 0, by_depth[np.maximum(top - 1, 0)], -1)
    src = np.r_[b.edges[:, 0], b.edges[:, 1]]
    dst = np.r_[b.edges[:, 1], b.edges[:, 0]]
    lip = rim[src]
    over = (lip >= 0) & (rim[dst] != lip) & (b.basin[dst] != lip) & (b.heights[dst] < b.heights[src] - b.level_tol)
    target, owner = dst[over], lip[over]
    count = np.bincount(owner, minlength=len(b.depth)).astype(np.float64)
    share = 1.0 / count[owner] if len(owner) else np.zeros(0)
    return SpillRoutes(b.basin, target, share, owner)


def spill_over(pooled: np.ndarray, routes: SpillRoutes) -> tuple[np.ndarray, np.ndarray]:
    """Carry ``pooled`` (n,) water (m^3) of full basins over their rims.

    Returns
    -------
    spilled : (n,) float
        Water arriving at the vertices outside the rims, m^3.
    kept : (n,) float
        What stays pooled: water in no basin (a dimple under the level tolerance) or in one
        with no way over its rim.
    """
    pooled = np.asarray(pooled, dtype=np.float64)
    held = (pooled > 0) & (routes.basin >= 0)
    per_basin = np.bincount(routes.basin[held], weights=pooled[held], minlength=int(routes.basin.max()) + 1)
    has_way = np.zeros(len(per_basin), dtype=bool)
    has_way[routes.owner] = True
    spilled = np.bincount(routes.target, weights=per_basin[routes.owner] * routes.share, minlength=len(pooled))
    kept = np.where(held & has_way[np.maximum(routes.basin, 0)], 0.0, pooled)
    return spilled, kept
