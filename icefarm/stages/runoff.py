"""Where a storm's film runs over a surface and what freezes on its way
(`icefarm.stages.storm.accrete`): each vertex's routes to its lower neighbours, and the
walk of the water down them in order, freezing, shedding and pooling."""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ..geometry import stable_order
from ..tol import tol

# The film goes to each lower neighbour in proportion to the slope towards it raised to
# this power (Freeman's multiple flow directions; 1 spreads it like a fan, infinity is one
# steepest chain): 4 keeps most of it downhill and still spreads it over a wall (one
# chain striped a car's doors).
FLOW_CONVERGENCE = 4.0


def film_routes(mesh: trimesh.Trimesh, g: np.ndarray, cos_up: np.ndarray, area: np.ndarray):
    """Where the water at each vertex goes next, and an order that visits every vertex
    after all those that feed it.

    A film spreads over a face rather than running in one channel: each vertex passes its
    water to all its lower edge neighbours, in proportion to the slope towards each raised
    to `FLOW_CONVERGENCE` (multiple flow directions; one steepest neighbour runs it down in stripes, which the
    glaze on a car's doors shows as dark streaks). A level, upward vertex with no lower
    neighbour (a table top) passes it across level edges towards the nearest vertex that has
    one; a downward vertex with none drips (an outlet); an upward one with no way out is a
    basin (it pools).

    Returns
    -------
    start : (n + 1,) int
        Vertex ``v``'s outgoing routes are ``start[v]:start[v + 1]`` (none: the water stops).
    target, share : (r,) int, (r,) float
        Each route's vertex and the share of the water it takes (a vertex's shares add to 1).
    step : (n,) float
        Mean length of a vertex's routes, meters (its own size where it has none).
    order : (n,) int
        Vertices from the highest down (level stretches: farthest from their edge first).
    outlet : (n,) bool
        Where a stop means dripping rather than pooling.
    """
    n = len(mesh.vertices)
    heights = mesh.vertices @ -g
    edges = np.asarray(mesh.edges_unique)
    length = np.maximum(mesh.edges_unique_length, 1e-12)
    drop_tol = tol.drop * float(np.linalg.norm(mesh.extents))
    drop = heights[edges[:, 0]] - heights[edges[:, 1]]
    src = np.r_[edges[:, 0], edges[:, 1]]
    dst = np.r_[edges[:, 1], edges[:, 0]]
    slope = np.r_[drop, -drop] / np.r_[length, length]
    run = np.r_[length, length]
    down = np.r_[drop, -drop] > drop_tol
    src, dst, slope, run = src[down], dst[down], slope[down], run[down]
    has_down = np.bincount(src, minlength=n) > 0
    flat_distance = np.zeros(n)
    # Level stretches: from upward vertices with no way down across level edges to one that has.
    upward_stuck = ~has_down & (cos_up > 0)
    level = np.abs(drop) <= drop_tol
    usable = level & (upward_stuck[edges[:, 0]] | upward_stuck[edges[:, 1]])
    if usable.any():
        a, b = edges[usable, 0], edges[usable, 1]
        graph = coo_matrix((np.r_[length[usable], length[usable]], (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()
        exits = np.unique(np.r_[a, b][~upward_stuck[np.r_[a, b]]])
        if len(exits):
            distance, pred, _ = dijkstra(graph, indices=exits, min_only=True, return_predecessors=True)
            reach = np.flatnonzero(upward_stuck & np.isfinite(distance) & (pred >= 0))
            hop = np.linalg.norm(mesh.vertices[pred[reach]] - mesh.vertices[reach], axis=1)
            src, dst = np.r_[src, reach], np.r_[dst, pred[reach]]
            slope, run = np.r_[slope, np.ones(len(reach))], np.r_[run, hop]
            flat_distance = np.where(np.isfinite(distance), distance, 0.0)
    by_src = stable_order(src)
    src, target, slope, run = src[by_src], dst[by_src], slope[by_src], run[by_src]
    start = np.searchsorted(src, np.arange(n + 1))
    weight = slope ** FLOW_CONVERGENCE
    total = np.bincount(src, weights=weight, minlength=n)
    share = weight / total[src]
    step = np.bincount(src, weights=share * run, minlength=n)
    stops = np.diff(start) == 0
    step[stops] = np.sqrt(np.maximum(area[stops], 0.0))
    order = np.lexsort((-flat_distance, -heights))
    outlet = stops & ~(cos_up > 0)
    return start, target, share, step, order, outlet


def run_film(catch, capacity, passing, tilt, routes, order, outlet):
    """Route the water in ``order`` (a Python loop: each vertex waits for all that feed it).
    A vertex freezes its own catch up to its budget, then the share
    ``passing`` of the water running through, within what is left of it; sheds as its tilt
    passes the tilt the water has seen (averaged over the water arriving: a maximum lets a
    trickle that passed a steep spot stop the shedding of all the water it joined); passes the rest on along its
    ``routes`` (`film_routes`' start, target, share). Returns frozen, shed and pooled water per vertex, m^3."""
    n = len(catch)
    start, target, share = (x.tolist() for x in routes)
    own = catch.astype(np.float64).tolist()
    inflow = [0.0] * n
    seen = [0.0] * n  # the tilt the arriving water already passed, summed weighted by that water
    cap, ps, tl, out = capacity.tolist(), passing.tolist(), tilt.tolist(), outlet.tolist()
    frozen, shed, pooled = [0.0] * n, [0.0] * n, [0.0] * n
    for v in order.tolist():
        c, r = own[v], inflow[v]
        if c + r <= 0.0:
            continue
        f = cap[v] if cap[v] < c else c
        g = min(ps[v] * r, cap[v] - f)
        frozen[v] = f + g
        w = c + r - f - g
        s, t = seen[v] / (c + r), tl[v]  # its own rain has passed no tilt
        first, last = start[v], start[v + 1]
        if first == last:
            if out[v] or t > 0.0:
                shed[v] = w
            else:
                pooled[v] = w
            continue
        if t > s:  # shed (t - s) of the water as it was before any shed, of what is left (1 - s)
            d = w * (t - s) / (1.0 - s) if s < 1.0 else w
            shed[v] = d
            w -= d
            s = t
        for k in range(first, last):
            u = target[k]
            inflow[u] += w * share[k]
            seen[u] += s * w * share[k]
    return np.asarray(frozen), np.asarray(shed), np.asarray(pooled)
