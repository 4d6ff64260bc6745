"""Compiled kernels of the glaze coat's narrow band (`icefarm.stages.surface.coat_band`).

The band evaluates the coat's signed distance at every lattice sample near the coat: a
nearest surface sample each, then a dozen small steps (the sample's plane, its sharp
edges, the thickness carried to the foot, the taper past the rim, the wall at excluded
samples). Done with numpy over arrays of samples, each step allocates and walks its own
temporaries, and pykdtree answers the nearest-sample queries at about 0.45 us each: on
Table 2's dragon (row c, 846 k lattice samples) the band takes 0.62 s of one core, 0.28 s of
it in the queries. Here each sample goes through every step at once, compiled (numba,
without the GIL: the band's threads share the cores), and its nearest sample is looked up
in a k-d tree (`point_tree`) among the leaves near its tile, gathered once for the tile's
eight samples and bounded by the tile's nearest sample (`_tile_nearest`): 0.27 s of one
core on the dragon.

The numpy version is kept in tests/test_coat_kernel.py as the reference: they
agree to 1e-12 m but where two samples lie alike far.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...compiled import compiled
from ...median_split import median_order, tree_boxes

# Points per leaf of a `PointTree`: consecutive in the tree's order.
LEAF = 8
# Under a sample's plane, the coat's bound falls this many meters per meter of lateral
# offset past the sample's reach, where no sharp edge (`coat_band.Edges`) says what lies
# there: the coat's hidden inner part, `coat.INNER` voxels deep, otherwise comes out beside a
# convex edge whose other side is dry, as sawtooth spikes up to 1 cm long along a fence's
# picket edges wet with thin rivulets. At the plane the bound meets the outer face's.
BESIDE = 3.0
_STACK = 128  # a tree of 2^60 leaves is never built
_GATHER = 4096  # leaves gathered around a tile at most (`_tile_nearest`)


@dataclass(frozen=True)
class PointTree:
    """Points (n, 3) in the tree's order (``points``; ``index`` their rows in ``source``),
    in leaves of `LEAF` under a complete binary tree of boxes: node k's children are 2k and
    2k + 1, the leaves ``leaves`` .. 2 ``leaves`` - 1 (``lo``, ``hi``: (2 leaves, 3))."""

    points: np.ndarray
    index: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    leaves: int
    source: np.ndarray  # the points as given (n, 3)

    def nearest(self, points: np.ndarray, upper: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """As `icefarm.spatial.nearest`: distance and row of the nearest point closer than
        ``upper`` to each of ``points`` (k, 3) (inf and -1 for none)."""
        q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _nearest_many(q, float(upper), *self.arrays())

    def nearest_in_tiles(self, points: np.ndarray, seed: np.ndarray, per: int,
                         upper: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """`nearest` of ``points`` (k, 3) that come in tiles of ``per`` around their mean,
        each tile's within ``upper`` of its ``seed`` row (one per tile; -1: none within
        ``upper`` plus its half-diagonal): `_tile_nearest`."""
        q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        seed = np.asarray(seed, dtype=np.int64)
        row, d2 = _tile_nearest(q, seed, np.zeros(len(seed), dtype=np.bool_), per, float(upper), self.source,
                                self.arrays())
        return np.where(row >= 0, np.sqrt(d2), np.inf), row

    def any_within(self, points: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """``(k,) bool``: whether a point of the tree lies within ``radii`` (k,) of each of
        ``points`` (k, 3), its distance computed as `nearest` computes it. Stops at the first
        one found, where `nearest` would go on to the nearest."""
        q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _any_within_many(q, np.ascontiguousarray(radii, dtype=np.float64).reshape(-1), *self.arrays())

    def arrays(self):
        return self.points, self.index, self.lo, self.hi, self.leaves


def point_tree(points: np.ndarray) -> PointTree | None:
    """A `PointTree` of ``points`` (n, 3) in meters; None for none.

    A k-d tree in the layout of a complete binary tree: each node's points split at its
    middle leaf across their widest extent (`icefarm.median_split.median_order`), then the boxes, level by
    level. (Morton order instead makes leaves of eight of the dragon's coat samples 8 mm
    across, median, where they lie 1.2 mm apart: 1.6 us a query.)
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(points)
    if n == 0:
        return None
    count = -(-n // LEAF)
    leaves = 1 << max(int(count - 1).bit_length(), 0)
    order = median_order(points, leaves, LEAF)
    sorted_points = points[order]
    lo, hi = tree_boxes(sorted_points[:, None, :], leaves, LEAF)
    return PointTree(sorted_points, order, lo, hi, leaves, points)


@compiled(inline="always")
def _box2(lo, hi, k, x, y, z):
    """Squared distance from (x, y, z) to node ``k``'s box."""
    dx = max(lo[k, 0] - x, 0.0, x - hi[k, 0])
    dy = max(lo[k, 1] - y, 0.0, y - hi[k, 1])
    dz = max(lo[k, 2] - z, 0.0, z - hi[k, 2])
    return dx * dx + dy * dy + dz * dz


@compiled(inline="always")
def _scan_leaf(points, index, leaves, k, x, y, z, best2, best):
    """The nearest of leaf node ``k``'s points to (x, y, z) if closer than sqrt(``best2``):
    its squared distance and row (else ``best2``, ``best``)."""
    start = (k - leaves) * LEAF
    for j in range(start, min(start + LEAF, len(points))):
        dx = points[j, 0] - x
        dy = points[j, 1] - y
        dz = points[j, 2] - z
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best2:
            best2 = d2
            best = index[j]
    return best2, best


@compiled()
def _nearest(x, y, z, best2, best, stack, points, index, lo, hi, leaves):
    """The nearest point to (x, y, z) closer than sqrt(``best2``) (``best``: a row known that
    close, or -1): its squared distance and row (``best2``, ``best`` when none is closer)."""
    top = 0
    stack[0] = 1
    while top >= 0:
        k = stack[top]
        top -= 1
        if _box2(lo, hi, k, x, y, z) >= best2:
            continue
        if k >= leaves:
            best2, best = _scan_leaf(points, index, leaves, k, x, y, z, best2, best)
        else:
            a = 2 * k
            da = _box2(lo, hi, a, x, y, z)
            db = _box2(lo, hi, a + 1, x, y, z)
            if da <= db:  # the nearer child is popped first
                if db < best2:
                    top += 1
                    stack[top] = a + 1
                if da < best2:
                    top += 1
                    stack[top] = a
            else:
                if da < best2:
                    top += 1
                    stack[top] = a
                if db < best2:
                    top += 1
                    stack[top] = a + 1
    return best2, best


@compiled()
def _any_within_many(q, radii, points, index, lo, hi, leaves):
    out = np.zeros(len(q), dtype=np.bool_)
    stack = np.empty(_STACK, dtype=np.int64)
    for m in range(len(q)):
        x, y, z, r = q[m, 0], q[m, 1], q[m, 2], radii[m]
        prune = r * r * (1.0 + 1e-9)  # the boxes' bound, with room for the rounding of sqrt(d2) <= r
        top = 0
        stack[0] = 1
        while top >= 0 and not out[m]:
            k = stack[top]
            top -= 1
            if _box2(lo, hi, k, x, y, z) > prune:
                continue
            if k >= leaves:
                start = (k - leaves) * LEAF
                for j in range(start, min(start + LEAF, len(points))):
                    dx = points[j, 0] - x
                    dy = points[j, 1] - y
                    dz = points[j, 2] - z
                    if np.sqrt(dx * dx + dy * dy + dz * dz) <= r:
                        out[m] = True
                        break
            else:
                top += 1
                stack[top] = 2 * k + 1
                top += 1
                stack[top] = 2 * k
    return out


@compiled()
def _nearest_many(q, upper, points, index, lo, hi, leaves):
    dist = np.full(len(q), np.inf)
    row = np.full(len(q), -1, dtype=np.int64)
    stack = np.empty(_STACK, dtype=np.int64)
    upper2 = upper * upper
    for m in range(len(q)):
        d2, i = _nearest(q[m, 0], q[m, 1], q[m, 2], upper2, -1, stack, points, index, lo, hi, leaves)
        if i >= 0:
            dist[m] = np.sqrt(d2)
            row[m] = i
    return dist, row


@compiled()
def _tile_nearest(points, seed, shared, per, reach, samples, tree):
    """Nearest ``samples`` row (-1: none within ``reach``) and squared distance of each of
    ``points`` (k, 3), in tiles of ``per`` whose points lie around their mean; ``seed`` and
    ``shared``, one per tile, as in `band_phi` (a shared tile's points take its seed, their
    distance not computed).

    A point's nearest sample lies no farther from it than its tile's seed does, so within
    that distance plus the point's offset from the tile's centre: the leaves of the tree
    within the largest of those of the tile's centre hold it. They are gathered once per
    tile (one descent instead of eight) and each point scans those not farther from it than
    its best so far. On 157 k lattice samples of the dragon's coat (Table 2, row c), one
    thread: 0.28 us a point, against 0.45 us descending the tree from each point seeded
    likewise and 0.49 us for pykdtree's query (the same answers).
    """
    points_t, index, lo, hi, leaves = tree
    n = len(points)
    near = np.full(n, -1, dtype=np.int64)
    dist2 = np.full(n, np.inf)
    stack = np.empty(_STACK, dtype=np.int64)
    gathered = np.empty(_GATHER, dtype=np.int64)
    reach2 = reach * reach
    for base in range(0, n, per):
        end = min(base + per, n)
        s = seed[base // per]
        if shared[base // per]:
            for m in range(base, end):
                near[m] = s
            continue
        if s < 0:  # no sample within reach of the centre plus the tile's half-diagonal
            continue
        cx, cy, cz = 0.0, 0.0, 0.0
        for m in range(base, end):
            cx += points[m, 0]
            cy += points[m, 1]
            cz += points[m, 2]
        cx, cy, cz = cx / (end - base), cy / (end - base), cz / (end - base)
        radius = 0.0
        for m in range(base, end):
            x, y, z = points[m, 0], points[m, 1], points[m, 2]
            b2 = (x - samples[s, 0]) ** 2 + (y - samples[s, 1]) ** 2 + (z - samples[s, 2]) ** 2
            if b2 < reach2:
                near[m], dist2[m] = s, b2
            else:
                dist2[m] = reach2
            radius = max(radius, np.sqrt(dist2[m]) + np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2))
        # the leaves within radius of the centre
        count = 0
        top = 0
        stack[0] = 1
        radius2 = radius * radius
        while top >= 0 and count <= len(gathered):
            k = stack[top]
            top -= 1
            if _box2(lo, hi, k, cx, cy, cz) >= radius2:
                continue
            if k >= leaves:
                if count < len(gathered):
                    gathered[count] = k
                count += 1
            else:
                top += 1
                stack[top] = 2 * k
                top += 1
                stack[top] = 2 * k + 1
        for m in range(base, end):
            x, y, z = points[m, 0], points[m, 1], points[m, 2]
            if count > len(gathered):  # too many to gather: descend from the point
                dist2[m], near[m] = _nearest(x, y, z, dist2[m], near[m], stack, points_t, index, lo, hi, leaves)
                continue
            best2, best = dist2[m], near[m]
            for c in range(count):
                k = gathered[c]
                if _box2(lo, hi, k, x, y, z) >= best2:
                    continue
                best2, best = _scan_leaf(points_t, index, leaves, k, x, y, z, best2, best)
            near[m], dist2[m] = best, best2
    return near, dist2


@compiled(inline="always")
def _bound(row, inward, level, across, across_level, i, x, y, z):
    """For a point (x, y, z) near sample ``i``: how far it lies past the sharp edges of
    its face along the sample's plane (meters, 0 where it does not or the face has none:
    `icefarm.stages.surface.coat_band.Edges`), and its height over the planes across them
    (the most of them; -inf where none)."""
    r = row[i]
    if r < 0:
        return 0.0, -np.inf
    off = level[r, 0] - (x * inward[r, 0, 0] + y * inward[r, 0, 1] + z * inward[r, 0, 2])
    up = x * across[r, 0, 0] + y * across[r, 0, 1] + z * across[r, 0, 2] - across_level[r, 0]
    for e in range(1, 3):
        if np.isfinite(level[r, e]):
            off = max(off, level[r, e] - (x * inward[r, e, 0] + y * inward[r, e, 1] + z * inward[r, e, 2]))
            up = max(up, x * across[r, e, 0] + y * across[r, e, 1] + z * across[r, e, 2] - across_level[r, e])
    return max(off, 0.0), up


@compiled(inline="always")
def _signed(vx, vy, vz, nx, ny, nz, dist, tol, past):
    """`icefarm.stages.surface.coat_band._signed` at one point: (d, sd, extra)."""
    sd = vx * nx + vy * ny + vz * nz
    extra = max(np.sqrt(max(dist * dist - sd * sd, 0.0)) - tol, 0.0)
    extra = max(extra, past)
    s = 1.0 if sd > 0.0 else (-1.0 if sd < 0.0 else 0.0)
    return s * np.sqrt(sd * sd + extra * extra), sd, extra


@compiled()
def band_phi(points, per, seed, shared, seg, reach, tol, tol_shared, taper_end,
             samples, normals, kind, t_value, t_slope, t_low, t_high, depth, tree,
             has_edges, e_row, e_inward, e_level, e_across, e_across_level,
             has_rim, rim_tree, rim_seg, rim_a, rim_b, rim_ta, rim_tb, rim_normal, edge,
             has_wall, wet_index, wet_tree, blocked_tree, box_lo, box_hi):
    """The coat's ``phi`` (meters, positive inside) at ``points`` (k, 3): see
    `icefarm.stages.surface.coat_band.sample_band`.

    The points come in tiles of ``per``; ``seed``, ``shared`` and ``seg`` hold one value per
    tile (not per point: a band of tens of millions of samples would repeat them in memory).
    ``seed``: the tile's nearest surface sample (-1: none within reach). Where ``shared``,
    that is each of its points' own (no crease near the tile: the same plane), its rim
    segment is ``seg`` (-1: none), its tolerance ``tol_shared``, and no sharp edge or wall
    counts (`sample_band`); elsewhere each point's nearest sample is found
    (`_tile_nearest`). Trees are `PointTree.arrays`.
    """
    near, dist2 = _tile_nearest(points, seed, shared, per, reach, samples, tree)
    phi = np.empty(len(points))
    stack = np.empty(_STACK, dtype=np.int64)
    reach2 = reach * reach
    for m in range(len(points)):
        x, y, z = points[m, 0], points[m, 1], points[m, 2]
        own = shared[m // per]
        i = near[m]
        if i >= 0:
            vx, vy, vz = x - samples[i, 0], y - samples[i, 1], z - samples[i, 2]
            d_s = np.sqrt(vx * vx + vy * vy + vz * vz) if own else np.sqrt(dist2[m])
        if i < 0:
            phi[m] = -reach
            continue
        k = kind[i]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        past, over = 0.0, -np.inf
        edged = has_edges and not own
        if edged:
            past, over = _bound(e_row, e_inward, e_level, e_across, e_across_level, i, x, y, z)
        t_tol = tol_shared if own else tol
        d, sd, extra = _signed(vx, vy, vz, nx, ny, nz, d_s, t_tol, past)
        d = max(d, over)
        lx, ly, lz = vx - sd * nx, vy - sd * ny, vz - sd * nz
        scale = min(1.0, t_tol / max(np.sqrt(lx * lx + ly * ly + lz * lz), 1e-300))
        lx, ly, lz = lx * scale, ly * scale, lz * scale
        t = -np.inf
        if k == 1:
            t = min(max(t_value[i] + t_slope[i, 0] * lx + t_slope[i, 1] * ly + t_slope[i, 2] * lz, t_low[i]),
                    t_high[i])
        elif k == 0 and has_rim:
            fx, fy, fz = x - sd * nx, y - sd * ny, z - sd * nz
            if own:
                j = seg[m // per]
            else:
                rp, ri, rlo, rhi, rleaves = rim_tree
                _, r = _nearest(fx, fy, fz, edge * edge, -1, stack, rp, ri, rlo, rhi, rleaves)
                j = rim_seg[r] if r >= 0 else -1
            if j >= 0:
                ex, ey, ez = rim_b[j, 0] - rim_a[j, 0], rim_b[j, 1] - rim_a[j, 1], rim_b[j, 2] - rim_a[j, 2]
                ax, ay, az = fx - rim_a[j, 0], fy - rim_a[j, 1], fz - rim_a[j, 2]
                u = min(max((ax * ex + ay * ey + az * ez) / max(ex * ex + ey * ey + ez * ez, 1e-300), 0.0), 1.0)
                ox, oy, oz = ax - u * ex, ay - u * ey, az - u * ez
                d_rim = np.sqrt(ox * ox + oy * oy + oz * oz)
                t_rim = rim_ta[j] + u * (rim_tb[j] - rim_ta[j])
                facing = nx * rim_normal[j, 0] + ny * rim_normal[j, 1] + nz * rim_normal[j, 2] > -0.5
                taper = t_rim * (1.0 - d_rim / edge)
                if facing and d_rim < edge and taper >= taper_end:
                    t = taper
        p = min(t - d, d + depth[i])
        if sd < 0.0 and extra > 0.0 and not np.isfinite(over):
            p = min(p, t - sd - BESIDE * extra)
        if has_wall and not own and k != 0:
            d_b = np.inf
            if (box_lo[0] <= x <= box_hi[0]) and (box_lo[1] <= y <= box_hi[1]) and (box_lo[2] <= z <= box_hi[2]):
                bp, bi, blo, bhi, bleaves = blocked_tree
                b2, r = _nearest(x, y, z, reach2, -1, stack, bp, bi, blo, bhi, bleaves)
                if r >= 0:
                    d_b = np.sqrt(b2)
            d_w = d_s
            if k == -1:
                d_b = min(d_b, d_w)
                wp, wi, wlo, whi, wleaves = wet_tree
                w2, r = _nearest(x, y, z, reach2, -1, stack, wp, wi, wlo, whi, wleaves)
                d_w = np.inf
                if r >= 0:
                    d_w = np.sqrt(w2)
                    j = wet_index[r]
                    past_j, over_j = 0.0, -np.inf
                    if has_edges:
                        past_j, over_j = _bound(e_row, e_inward, e_level, e_across, e_across_level, j, x, y, z)
                    dj = _signed(x - samples[j, 0], y - samples[j, 1], z - samples[j, 2],
                                 normals[j, 0], normals[j, 1], normals[j, 2], d_w, tol, past_j)[0]
                    dj = max(dj, over_j)
                    p = min(t_value[j] - dj, dj + depth[j])
            w = 0.5 * (d_b - d_w)
            p = w if np.isnan(w) else min(p, w)
        phi[m] = p if (np.isfinite(p) and d < reach) else -reach
    return phi
