"""A compiled tree of triangles that finds the first hit along a ray, for loops that cast a
ray or two per step of their own (the trajectory stage's slides, `icefarm.stages.slide_kernel`).

Embree (`icefarm.spatial.ray_caster`) casts big batches fast, but each call from Python
costs about 18 us, and a slide takes two casts per step of a few rays each. Here a cast is
a function call inside the compiled loop: on Table 2's row f (the 0.2 m bunny, 11 k faces,
200 icicles) the slides take 11-15 ms a run instead of 63-73 ms. Distances are in float64 (Embree's
are float32): they agree to 1e-6 of the mesh's size (tests/test_triangle_tree.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .compiled import compiled
from .median_split import median_order, tree_boxes

LEAF = 4  # triangles per leaf
STACK_SIZE = 128  # for `first_hit`: a tree of 2^60 leaves is never built
_HUGE = 1e300  # the inverse of a direction's zero component


@dataclass(frozen=True)
class TriangleTree:
    """Triangles in the tree's order (``corner`` (n, 3), the first vertex; ``edge1``,
    ``edge2`` (n, 3) from it to the others; ``index`` their rows in the mesh's faces), in
    leaves of `LEAF` under a complete binary tree of boxes: node k's children are 2k and
    2k + 1, the leaves ``leaves`` .. 2 ``leaves`` - 1 (``lo``, ``hi``: (2 leaves, 3))."""

    corner: np.ndarray
    edge1: np.ndarray
    edge2: np.ndarray
    index: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    leaves: int

    def cast(self, origins: np.ndarray, directions: np.ndarray, far: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """As `icefarm.spatial.ray_caster`'s ``cast``: distance (k,) along each unit
        direction to the first hit within ``far`` (inf for none) and its face (-1)."""
        o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        distance, face = _cast_many(o, d, self.arrays())
        beyond = distance > far
        distance[beyond], face[beyond] = np.inf, -1
        return distance, face

    def arrays(self):
        """The tree as the compiled functions take it (`first_hit`'s ``tree``)."""
        return self.corner, self.edge1, self.edge2, self.index, self.lo, self.hi, self.leaves


def triangle_tree(vertices: np.ndarray, faces: np.ndarray) -> TriangleTree:
    """The `TriangleTree` of a mesh's ``faces`` (m, 3) over ``vertices`` (n, 3), meters.

    Leaves hold the triangles whose centroids `icefarm.median_split.median_order` puts
    together; each node's box bounds its triangles whole.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    count = max(-(-len(faces) // LEAF), 1)
    leaves = 1 << int(count - 1).bit_length()
    tris = vertices[faces]
    order = median_order(tris.mean(axis=1), leaves, LEAF) if len(faces) else np.zeros(0, dtype=np.int64)
    tris = tris[order]
    corner = np.ascontiguousarray(tris[:, 0])
    lo, hi = tree_boxes(tris, leaves, LEAF)
    return TriangleTree(corner, np.ascontiguousarray(tris[:, 1] - corner), np.ascontiguousarray(tris[:, 2] - corner),
                        order, lo, hi, leaves)


@compiled(inline="always")
def _enter(lo, hi, k, o, inv, best):
    """Where the ray ``o + t d`` (``inv``: 1 / d per axis) enters node ``k``'s box, or inf
    where it misses it or enters past ``best``."""
    t_in, t_out = 0.0, best
    for a in range(3):
        t0 = (lo[k, a] - o[a]) * inv[a]
        t1 = (hi[k, a] - o[a]) * inv[a]
        t_in = max(t_in, min(t0, t1))
        t_out = min(t_out, max(t0, t1))
    return t_in if t_in <= t_out else np.inf


@compiled()
def first_hit(o, d, stack, tree):
    """Distance along ``d`` (3,) from ``o`` (3,) to the first triangle of ``tree``
    (`TriangleTree.arrays`) hit (t > 0), and its face (inf and -1 for none); ``stack``: a
    scratch (`STACK_SIZE`,) int64 array.

    Moller-Trumbore's test on each triangle of the leaves whose boxes the ray enters, nearer
    child first.
    """
    corner, edge1, edge2, index, lo, hi, leaves = tree
    inv = np.empty(3)
    for a in range(3):
        inv[a] = 1.0 / d[a] if d[a] != 0.0 else _HUGE
    best, face = np.inf, -1
    if len(corner) == 0 or _enter(lo, hi, 1, o, inv, best) == np.inf:
        return best, face
    top = 0
    stack[0] = 1
    while top >= 0:
        k = stack[top]
        top -= 1
        if k >= leaves:
            start = (k - leaves) * LEAF
            for j in range(start, min(start + LEAF, len(corner))):
                e1x, e1y, e1z = edge1[j, 0], edge1[j, 1], edge1[j, 2]
                e2x, e2y, e2z = edge2[j, 0], edge2[j, 1], edge2[j, 2]
                px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
                det = e1x * px + e1y * py + e1z * pz
                if det == 0.0:
                    continue
                r = 1.0 / det
                sx, sy, sz = o[0] - corner[j, 0], o[1] - corner[j, 1], o[2] - corner[j, 2]
                u = (sx * px + sy * py + sz * pz) * r
                if u < 0.0 or u > 1.0:
                    continue
                qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
                v = (d[0] * qx + d[1] * qy + d[2] * qz) * r
                if v < 0.0 or u + v > 1.0:
                    continue
                t = (e2x * qx + e2y * qy + e2z * qz) * r
                if 0.0 < t < best:
                    best, face = t, index[j]
            continue
        a = 2 * k
        ta = _enter(lo, hi, a, o, inv, best) if lo[a, 0] <= hi[a, 0] else np.inf
        tb = _enter(lo, hi, a + 1, o, inv, best) if lo[a + 1, 0] <= hi[a + 1, 0] else np.inf
        if ta <= tb:  # the nearer child is popped first
            if tb < np.inf:
                top += 1
                stack[top] = a + 1
            if ta < np.inf:
                top += 1
                stack[top] = a
        else:
            if ta < np.inf:
                top += 1
                stack[top] = a
            if tb < np.inf:
                top += 1
                stack[top] = a + 1
    return best, face


@compiled()
def _cast_many(o, d, tree):
    dist = np.full(len(o), np.inf)
    face = np.full(len(o), -1, dtype=np.int64)
    stack = np.empty(STACK_SIZE, dtype=np.int64)
    for m in range(len(o)):
        dist[m], face[m] = first_hit(o[m], d[m], stack, tree)
    return dist, face
