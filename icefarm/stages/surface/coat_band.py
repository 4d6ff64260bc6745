"""The glaze coat's narrow band (`coat`): lattice samples near the coat, their signed
distance from the surface samples, and its encoding as a field.

Only the narrow band is sampled: tiles of the lattice found coarse to fine, each
kept where its centre's distance says the coat may come within a voxel of it; where no
crease or change of wet/dry/excluded comes near, the samples of a tile share their
centre's nearest surface sample (one plane: the same distance, exactly). The result has
the block layout of `icefarm.metaballs.Field` and is stored so that marching cubes,
which interpolates ``value ** MARCH_POWER`` linearly (`icefarm.metaballs.march._march_domain`),
interpolates the signed distance itself: the iso-surface lies where the distance says,
to a fraction of a voxel, and fuses with the icicles' field through
`icefarm.metaballs.fuse_fields`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from ...errors import InputError
from ...geometry import nearest, point_index
from ...metaballs.field import BLOCK, CUTOFF, Field, block_keys
from ...metaballs.march import MARCH_POWER

# Signed distance (in voxels) over which the stored field goes from the level to twice
# it (after ``** MARCH_POWER``): marching cubes sees a linear ramp through the surface.
_RAMP = 2.0
# Edge of a tile (lattice samples) of the narrow band: tiles far from the coat are skipped.
_TILE = 2
# Tiles are found coarse to fine: from tiles of _TILE * 2^_LEVELS samples down to _TILE.
_LEVELS = 2
# The lattice's origin sits this many blocks off a multiple of a block (irrational voxels).
_SHIFT = 1.0 + (math.sqrt(5.0) - 2.0) / BLOCK
# Refuse coats whose field would need more memory than this, or more lattice samples
# evaluated than this (about 100 bytes each on the way).
_MAX_FIELD_BYTES = 2 * 2**30
MAX_BAND_POINTS = 60_000_000
# Lattice samples evaluated at once, by each thread in turn. The dozen temporaries of (k, 3)
# floats then stay in a 32 MB L3 cache: on Table 2's dragon (846 k samples, 2 threads) the
# band took a median 0.46 s against 0.51 s in chunks of 1,000,000 (two alternated rounds of
# four; 65,536 and 262,144 no better), with the same field bit for bit.
_CHUNK_POINTS = 131_072
# The taper past the rim ends where it would be thinner than this, in voxels, instead of
# thinning to nothing: a coat whose outer face runs within a ray's offset (about 0.1 mm in a
# scene a metre across) of the object's surface let Mitsuba's refracted rays start under the
# object, and its ragged line of contact rendered as black cracks on the fountain's basin
# wall at 1920 x 1080. A quarter voxel is below what marching cubes places to begin with.
TAPER_END = 0.25
# Under a sample's plane, the coat's bound falls this many meters per meter of lateral
# offset past the sample's reach, where no sharp edge (`Edges`) says what lies there: the
# coat's hidden inner part, ``INNER`` voxels deep, otherwise came out beside a convex edge
# whose other side is dry, as sawtooth spikes up to 1 cm long along a fence's picket edges
# wet with thin rivulets. At the plane the bound meets the outer face's.
_BESIDE = 3.0


@dataclass(frozen=True)
class Thickness:
    """The coat's thickness at the surface samples (meters): ``value`` (k,) at each, carried
    to a point ``lateral`` (k, 3) away along ``slope`` (k, 3, m/m) and kept within ``low`` ..
    ``high`` (k,), the range around the sample's face (0 for dry samples)."""

    value: np.ndarray
    slope: np.ndarray
    low: np.ndarray
    high: np.ndarray

    def at(self, i: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        return np.clip(self.value[i] + np.einsum("kd,kd->k", self.slope[i], lateral), self.low[i], self.high[i])


@dataclass(frozen=True)
class Edges:
    """Sharp convex edges that bound the surface samples' planes: sample ``s`` with
    ``row[s] >= 0`` lies in the plane of a face bounded by up to 3 such edges, each the line
    ``x . inward[row, e] = level[row, e]`` in that plane; ``inward`` (m, 3, 3) unit vectors
    in the plane pointing from the edge towards the face, ``level`` (m, 3) in meters
    (-inf: no edge). Across edge ``e`` the surface goes on in the plane
    ``x . across[row, e] = across_level[row, e]`` (outward unit normal, meters)."""

    row: np.ndarray
    inward: np.ndarray
    level: np.ndarray
    across: np.ndarray
    across_level: np.ndarray

    def bound(self, i: np.ndarray, points: np.ndarray):
        """For ``points`` (k, 3) near sample ``i`` (k,): how far each lies past the edges
        along the sample's plane (meters, 0 where it does not or ``i`` has none), and its
        height over the planes across them (the most of them; -inf where none)."""
        past = np.zeros(len(points))
        over = np.full(len(points), -np.inf)
        sel = np.flatnonzero(self.row[i] >= 0)
        if len(sel):
            r = self.row[i[sel]]
            p = points[sel]
            off = self.level[r, 0] - np.einsum("kd,kd->k", p, self.inward[r, 0])
            up = np.einsum("kd,kd->k", p, self.across[r, 0]) - self.across_level[r, 0]
            for e in (1, 2):  # most faces have one edge: the second and third only where there
                more = np.flatnonzero(np.isfinite(self.level[r, e]))
                if len(more):
                    rm, pm = r[more], p[more]
                    off[more] = np.maximum(off[more], self.level[rm, e] - np.einsum("kd,kd->k", pm, self.inward[rm, e]))
                    up[more] = np.maximum(up[more], np.einsum("kd,kd->k", pm, self.across[rm, e]) - self.across_level[rm, e])
            past[sel] = np.maximum(off, 0.0)
            over[sel] = up
        return past, over


def sample_band(pts, normals, thick: Thickness, kind, depth, rim, features, sole, edge, voxel, reach, h,
                name, edges: Edges | None = None) -> Field | None:
    """The coat's field on the lattice tiles near the wet samples.

    ``kind`` per sample: 1 wet, 0 dry, -1 excluded. Each lattice sample takes its nearest
    surface sample ``s`` (normal ``n``): ``sd = (p - s) . n``, its lateral offset beyond
    the sample spacing ``l``, the signed distance ``D = sign(sd) sqrt(sd^2 + l^2)`` and
    ``phi = min(T - D, D + depth)`` (positive inside); T is the thickness of a wet ``s``
    carried to the foot ``p - sd n`` (`Thickness.at`) and, past the rim, that of the
    nearest rim point times ``1 - d / edge`` (d: distance from the foot to the rim). No
    coat where ``s`` is excluded, lies past the taper or farther than ``reach``. Between wet
    and excluded samples (and the excluded vertices ``sole``) the coat ends in a wall at
    their bisector, ``phi = (dB - dW) / 2``. With ``edges``, the lateral offset counts from
    a sharp convex edge of ``s``'s face too, and D is at least the height over the plane
    across that edge (`Edges.bound`: a convex solid's signed distance is the largest of its
    planes'): beyond the edge the face's plane is not the surface.
    """
    wet = kind == 1
    blocked = np.concatenate([pts[kind == -1], sole])
    wall = (np.flatnonzero(wet), point_index(pts[wet]), point_index(blocked), blocked.min(axis=0) - reach,
            blocked.max(axis=0) + reach) if len(blocked) else None
    inner, inner_lo = float(depth.max()), float(depth.min())
    pad = BLOCK * voxel + reach  # the lattice's first block stays empty (see _halo_blocks)
    # Off the round coordinates by a fraction of a voxel: faces of boxes and prisms then
    # never lie on lattice planes (samples exactly on the iso-surface).
    origin = (np.floor((pts.min(axis=0) - pad) / (BLOCK * voxel)) - _SHIFT) * (BLOCK * voxel)
    # Coarse tiles within reach of a wet sample, each with bounds on the coat's thickness
    # within reach of it (dry and excluded samples count as 0) ...
    size = _TILE * 2 ** _LEVELS
    k = int(math.ceil(reach / (size * voxel)))
    keys = block_keys(np.floor((pts - origin) / (size * voxel)).astype(np.int64))
    keys, t_lo, t_hi, has_wet = _reduce(keys, np.where(wet, thick.low, 0.0), np.where(wet, thick.high, 0.0), wet)
    for shift in (42, 21, 0):  # separable dilation by k tiles, one axis at a time
        step = np.arange(-k, k + 1) << shift
        keys, t_lo, t_hi, has_wet = _reduce((keys[:, None] + step[None, :]).ravel(), *(
            np.repeat(a, len(step)) for a in (t_lo, t_hi, has_wet)))
    keys, t_lo, t_hi = keys[has_wet], t_lo[has_wet], t_hi[has_wet]
    if len(keys) * size**3 > 8 * MAX_BAND_POINTS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze ({len(keys) * size**3} lattice "
            f"samples within reach of the coat); raise {name}")
    tiles = np.stack([keys >> 42, (keys >> 21) & (2**21 - 1), keys & (2**21 - 1)], axis=1)
    # ... then, level by level down to _TILE, tiles are dropped where their centre says
    # none of their samples is within a voxel of the coat, kept whole where it says all
    # are more than a voxel inside it, and split in eight otherwise.
    tree = point_index(pts)
    children = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    solid = []
    while True:
        half = 0.5 * math.sqrt(3) * (size - 1) * voxel
        centre = origin + (tiles * size + 0.5 * (size - 1)) * voxel
        dist, idx = nearest(tree, centre, reach + half)
        d_c = np.full(len(centre), np.inf)
        found = idx >= 0
        d_c[found] = _signed(centre[found] - pts[idx[found]], normals[idx[found]], dist[found], 0.6 * h)[0]
        near = half + voxel
        inside = (d_c > near - inner_lo) & (d_c < t_lo - near)
        if edges is not None:  # the centre's plane may not hold past a sharp edge: no solid tile
            inside[found] &= edges.row[idx[found]] < 0
        keep = (d_c > -(inner + near)) & (d_c < t_hi + near) & ~inside
        if inside.any():
            n_sub = size // _TILE
            sub = np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
            solid.append((tiles[inside][:, None, :] * n_sub + sub[None]).reshape(-1, 3))
        tiles, t_lo, t_hi = tiles[keep], t_lo[keep], t_hi[keep]
        if size == _TILE:
            near_sample = idx[keep]
            # A tile's samples share its centre's nearest surface sample where no crease or
            # change of kind comes near enough to give any of them another (their nearest
            # lies within dist + 2 half of the centre).
            shared = found[keep].copy()
            if features is not None and shared.any():
                bound = dist[keep][shared] + 2.0 * half + h
                d_f, _ = nearest(features, centre[keep][shared], bound.max())
                shared[shared] = d_f > bound
            # Shared dry tiles share the rim segment nearest to their centre too.
            rim_seg = None
            dry = shared & (kind[np.maximum(near_sample, 0)] == 0)
            if rim is not None and dry.any():
                rim_seg = np.full(len(tiles), -1)
                c, j = centre[keep][dry], near_sample[dry]
                foot = c - np.einsum("kd,kd->k", c - pts[j], normals[j])[:, None] * normals[j]
                rim_seg[dry] = rim.query(foot, edge + 2.0 * half)
            break
        size //= 2
        tiles = (2 * tiles[:, None, :] + children[None]).reshape(-1, 3)
        t_lo, t_hi = np.repeat(t_lo, 8), np.repeat(t_hi, 8)
    npoints = len(tiles) * _TILE**3
    if npoints > MAX_BAND_POINTS or npoints * 4 > _MAX_FIELD_BYTES:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze ({npoints} lattice samples "
            f"near the coat, at most {MAX_BAND_POINTS}); raise {name}")
    o = np.arange(_TILE)
    local = np.stack(np.meshgrid(o, o, o, indexing="ij"), axis=-1).reshape(-1, 3)
    values = np.empty(npoints, dtype=np.float32)

    def evaluate(lo: int, hi: int) -> None:
        p = origin + (tiles[lo:hi, None, :] * _TILE + local[None]).reshape(-1, 3) * voxel
        # Where the surface is flat around a tile, its samples share the centre's nearest
        # surface sample (the same plane: the same distance); elsewhere each finds its own.
        flat = np.repeat(shared[lo:hi], _TILE**3)
        phi = np.empty(len(p))
        phi[flat] = _phi(tree, pts, p[flat], normals, thick, kind, rim, edge, depth, reach, 0.6 * h + half,
                         np.repeat(near_sample[lo:hi], _TILE**3)[flat],
                         None if rim_seg is None else np.repeat(rim_seg[lo:hi], _TILE**3)[flat],
                         taper_end=TAPER_END * voxel)
        phi[~flat] = _phi(tree, pts, p[~flat], normals, thick, kind, rim, edge, depth, reach, 0.6 * h, wall=wall,
                          taper_end=TAPER_END * voxel, edges=edges)
        values[lo * _TILE**3:hi * _TILE**3] = _encode(phi, voxel)

    # Chunks of tiles on every core: the queries and most numpy work release the GIL. Each
    # chunk's tree queries stay on its own thread: pykdtree would start an OpenMP team of
    # every core in each (cores^2 threads on a render node).
    threads = os.cpu_count() or 1
    chunk = max(1, min(_CHUNK_POINTS // _TILE**3, -(-len(tiles) // threads)))

    def evaluate_alone(lo: int) -> None:
        with threadpool_limits(limits=1, user_api="openmp"):
            evaluate(lo, min(lo + chunk, len(tiles)))

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(evaluate_alone, range(0, len(tiles), chunk)))
    if solid:  # more than a voxel inside: any value above the level marches the same
        solid = np.concatenate(solid)
        tiles = np.concatenate([tiles, solid])
        values = np.r_[values, np.full(len(solid) * _TILE**3, _encode(np.array([voxel]), voxel)[0])]
    if len(tiles) == 0:
        return None
    # Tiles into blocks (block_keys order); absent tiles of a block stay 0 (outside).
    per = BLOCK // _TILE
    bc = tiles // per
    keys = block_keys(bc)
    ukeys, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    if len(ukeys) * BLOCK**3 * 4 > _MAX_FIELD_BYTES:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze: its field needs "
            f"{len(ukeys) * BLOCK**3 * 4 / 2**30:.1f} GiB (at most {_MAX_FIELD_BYTES / 2**30:.0f}); raise {name}")
    blocks = bc[first]
    out = np.zeros((len(ukeys), BLOCK, BLOCK, BLOCK), dtype=np.float32)
    t_in = tiles - bc * per
    vals = values.reshape(len(tiles), _TILE, _TILE, _TILE)
    ix = t_in[:, 0, None] * _TILE + o[None, :]
    iy = t_in[:, 1, None] * _TILE + o[None, :]
    iz = t_in[:, 2, None] * _TILE + o[None, :]
    out[inverse.reshape(-1)[:, None, None, None], ix[:, :, None, None], iy[:, None, :, None],
        iz[:, None, None, :]] = vals
    return Field(origin.astype(np.float64), voxel, 1.0, blocks.astype(np.int64), out)


def _reduce(keys, t_lo, t_hi, flag):
    """Per distinct key: the least ``t_lo``, the greatest ``t_hi``, any ``flag``."""
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    start = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return (keys[start], np.minimum.reduceat(t_lo[order], start), np.maximum.reduceat(t_hi[order], start),
            np.logical_or.reduceat(flag[order], start))


def _signed(v, n, dist, tol, past=None):
    """Signed distance from offsets ``v`` (k, 3) to samples of normal ``n``: the height
    over the sample's plane, rounded off with the lateral offset past ``tol`` (or past a
    sharp edge, ``past``, where farther). Returns it, the height and that offset."""
    sd = np.einsum("kd,kd->k", v, n)
    extra = np.maximum(np.sqrt(np.maximum(dist**2 - sd**2, 0.0)) - tol, 0.0)
    if past is not None:
        extra = np.maximum(extra, past)
    return np.sign(sd) * np.sqrt(sd**2 + extra**2), sd, extra


def _phi(tree, samples, points, normals, thick: Thickness, kind, rim, edge, depth, reach, tol, near=None, seg=None,
         wall=None, taper_end=0.0, edges: Edges | None = None):
    """``phi`` (meters, positive inside the coat) at ``points`` (see `sample_band`), from
    their nearest ``samples`` (indices ``near``, -1 for none; queried in ``tree``, their
    `icefarm.geometry.point_index`, when not given).

    The points of a dry sample lie past the rim: the coat there tapers with the distance
    to the nearest rim segment, found per point or given (``seg``, -1: none near; the
    samples of a tile sharing one, `sample_band`). With ``wall`` (wet sample indices,
    a tree of the wet samples, one of the excluded ones, and the excluded ones' box widened
    by ``reach``: lowest and highest corners), the coat stops at the bisector between wet
    and excluded samples. The taper ends where it would be thinner than
    ``taper_end`` (meters). ``edges``: see `sample_band`.
    """
    if near is None:
        dist, near = nearest(tree, points, reach)
        found = np.flatnonzero(near >= 0)
        i = near[found]
        v = points[found] - samples[i]
        d_s = dist[found]
    else:
        found = np.flatnonzero(near >= 0)
        i = near[found]
        v = points[found] - samples[i]
        d_s = np.sqrt(np.einsum("kd,kd->k", v, v))
    phi = np.full(len(points), -reach)
    k = kind[i]
    past, over = (None, None) if edges is None else edges.bound(i, points[found])
    d, sd, extra = _signed(v, normals[i], d_s, tol, past)
    if over is not None:  # near a convex edge the solid lies under both planes: the farther
        d = np.maximum(d, over)
    # The thickness's slope is carried no farther than the sample's reach: past a convex
    # corner, where a point's nearest sample may lie a centimetre to the side, the slopes
    # of a corner's small faces (0.4-0.5 m/m on a fence's picket tops) carried that far
    # disagreed by 6 mm between neighbouring lattice samples and left flecks of coat.
    lateral = v - sd[:, None] * normals[i]
    lateral *= np.minimum(1.0, tol / np.maximum(np.sqrt(np.einsum("kd,kd->k", lateral, lateral)), 1e-300))[:, None]
    t = np.where(k == 1, thick.at(i, lateral), -np.inf)
    dry = np.flatnonzero(k == 0)
    if rim is not None and len(dry):
        foot = points[found[dry]] - sd[dry, None] * normals[i[dry]]
        j = rim.query(foot, edge) if seg is None else seg[found[dry]]
        dry, foot, j = dry[j >= 0], foot[j >= 0], j[j >= 0]
        d_rim, t_rim = rim.near(foot, j)
        facing = np.einsum("kd,kd->k", normals[i[dry]], rim.normal[j]) > -0.5
        taper = t_rim * (1.0 - d_rim / edge)
        t[dry] = np.where(facing & (d_rim < edge) & (taper >= taper_end), taper, -np.inf)
    p = np.minimum(t - d, d + depth[i])
    # Under the sample's plane but past its reach the point may lie beside a convex edge,
    # outside the object: the coat's hidden inner part must not come out there. (Past a
    # sharp edge of the sample's face the plane across says how far out it lies.)
    beside = (sd < 0) & (extra > 0)
    if over is not None:
        beside &= ~np.isfinite(over)
    beside = np.flatnonzero(beside)
    p[beside] = np.minimum(p[beside], t[beside] - sd[beside] - _BESIDE * extra[beside])
    if wall is not None:
        wet_index, wet_tree, blocked_tree, blocked_lo, blocked_hi = wall
        sel = np.flatnonzero(k != 0)  # nearest to a wet or an excluded sample
        q = points[found[sel]]
        # Only points in the excluded samples' box, widened by reach, can have one within
        # reach (the sole an object stands on is a small part of it: a query each was 7 %
        # of the band's time on Table 2's dragon).
        d_b = np.full(len(q), np.inf)
        boxed = np.ones(len(q), dtype=bool)
        for a in range(3):
            boxed &= (q[:, a] >= blocked_lo[a]) & (q[:, a] <= blocked_hi[a])
        boxed = np.flatnonzero(boxed)
        d_b[boxed] = nearest(blocked_tree, q[boxed], reach)[0]
        d_w = d_s[sel]
        cut = np.flatnonzero(k[sel] == -1)
        if len(cut):  # nearest to an excluded sample: the coat of the nearest wet one, walled
            d_b[cut] = np.minimum(d_b[cut], d_w[cut])
            d_cut, j = nearest(wet_tree, q[cut], reach)
            ok = j >= 0
            d_w[cut] = d_cut
            cut, j, d_cut = cut[ok], wet_index[j[ok]], d_cut[ok]
            past_j, over_j = (None, None) if edges is None else edges.bound(j, q[cut])
            dj = _signed(q[cut] - samples[j], normals[j], d_cut, tol, past_j)[0]
            if over_j is not None:
                dj = np.maximum(dj, over_j)
            p[sel[cut]] = np.minimum(thick.value[j] - dj, dj + depth[j])
        p[sel] = np.minimum(p[sel], 0.5 * (d_b - d_w))
    phi[found] = np.where(np.isfinite(p) & (d < reach), p, -reach)
    return phi


def _encode(phi: np.ndarray, voxel: float) -> np.ndarray:
    """Field values whose ``** MARCH_POWER`` is linear in ``phi`` around the level 1."""
    ramp = _RAMP * voxel
    low = CUTOFF**MARCH_POWER  # march clamps the field at CUTOFF * level (level 1)
    g = np.clip(1.0 + phi / ramp, low, 2.0)
    return (g ** (1.0 / MARCH_POWER)).astype(np.float32)
