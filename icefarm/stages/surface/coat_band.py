"""The glaze coat's narrow band (`coat`): lattice samples near the coat, their signed
distance from the surface samples, and its encoding as a field.

Only the narrow band is sampled: tiles of the lattice found coarse to fine, each
kept where its centre's distance says the coat may come within a voxel of it; where no
crease or change of wet/dry/excluded comes near, the samples of a tile share their
centre's nearest surface sample (one plane: the same distance, exactly). The result has
the block layout of `icefarm.metaballs.Field` and is stored so that marching cubes,
which interpolates ``value ** MARCH_POWER`` linearly (`icefarm.metaballs.march_kernel`),
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

from ...errors import InputError
from ...metaballs.field import BLOCK, CUTOFF, Field, block_keys
from ...metaballs.march_kernel import MARCH_POWER
from .coat_kernel import band_phi, point_tree

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
# Lattice samples evaluated at once, by each thread in turn (`band_phi` and the encoding's
# temporaries stay in cache).
_CHUNK_POINTS = 131_072
# The taper past the rim ends where it would be thinner than this, in voxels, instead of
# thinning to nothing: a coat whose outer face runs within a ray's offset (about 0.1 mm in a
# scene a metre across) of the object's surface lets Mitsuba's refracted rays start under the
# object, and its ragged line of contact renders as black cracks on the fountain's basin
# wall at 1920 x 1080. A quarter voxel is below what marching cubes places to begin with.
TAPER_END = 0.25


@dataclass(frozen=True)
class Thickness:
    """The coat's thickness at the surface samples (meters): ``value`` (k,) at each, carried
    to a point ``lateral`` (k, 3) away along ``slope`` (k, 3, m/m) and kept within ``low`` ..
    ``high`` (k,), the range around the sample's face (0 for dry samples)."""

    value: np.ndarray
    slope: np.ndarray
    low: np.ndarray
    high: np.ndarray


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


@dataclass(frozen=True)
class BandSamples:
    """The surface samples a coat's band is measured from (`sample_band`).

    Attributes
    ----------
    points : (k, 3) float
        On the wet faces and the faces around them, in meters.
    normals : (k, 3) float
        Outward unit normal of each sample's face.
    kind : (k,) int
        1 wet, 0 dry, -1 excluded.
    thickness : Thickness
        The coat's thickness at the samples, in meters (0 at dry and excluded ones).
    depth : (k,) float
        How deep under each sample the coat's inner face lies, in meters.
    edges : Edges, optional
        The sharp convex edges that bound the samples' planes.
    """

    points: np.ndarray
    normals: np.ndarray
    kind: np.ndarray
    thickness: Thickness
    depth: np.ndarray
    edges: Edges | None = None


@dataclass(frozen=True)
class BandLattice:
    """The lattice a coat's band is sampled on (`sample_band`).

    Attributes
    ----------
    voxel : float
        Lattice spacing, in meters.
    reach : float
        No coat farther than this from a wet sample, in meters.
    spacing : float
        Spacing of the surface samples, in meters: a lateral offset of up to 0.6 of it from
        the nearest sample counts as on its plane.
    edge : float
        Past the rim the coat thins linearly to nothing over this distance, in meters (>= 0).
    name : str
        The parameter that set ``voxel``, named in errors.
    """

    voxel: float
    reach: float
    spacing: float
    edge: float = 0.0
    name: str = "glaze.voxel_size"


@dataclass(frozen=True)
class _Tiles:
    """The finest tiles of the band (`_refine`), ``_TILE`` lattice samples on an edge.

    Attributes
    ----------
    tiles : (m, 3) int64
        Tiles within a voxel of the coat, in tiles from the lattice's origin.
    nearest : (m,) int64
        Each tile's centre's nearest surface sample (-1: none within reach).
    shared : (m,) bool
        Tiles whose samples all share that nearest sample.
    seg : (m,) int64
        The rim segment nearest to a shared dry tile's centre (-1: none, or not one).
    solid : (s, 3) int64
        Tiles all of whose samples lie more than a voxel inside the coat.
    """

    tiles: np.ndarray
    nearest: np.ndarray
    shared: np.ndarray
    seg: np.ndarray
    solid: np.ndarray


def sample_band(samples: BandSamples, lattice: BandLattice, rim, features, sole: np.ndarray) -> Field | None:
    """The coat's field on the lattice tiles near the wet samples.

    Each lattice sample takes its nearest surface sample ``s`` (normal ``n``):
    ``sd = (p - s) . n``, its lateral offset beyond the sample spacing ``l``, the signed
    distance ``D = sign(sd) sqrt(sd^2 + l^2)`` and ``phi = min(T - D, D + depth)``
    (positive inside); T is the thickness of a wet ``s`` carried to the foot ``p - sd n``
    (along its slope, within its range: `Thickness`) and, past the rim, that of the nearest
    rim point times ``1 - d / edge`` (d: distance from the foot to the rim). No coat where
    ``s`` is excluded, lies past the taper or farther than ``reach``. Between wet and
    excluded samples (and the excluded vertices ``sole``) the coat ends in a wall at their
    bisector, ``phi = (dB - dW) / 2``. With ``edges``, the lateral offset counts from a sharp
    convex edge of ``s``'s face too, and D is at least the height over the plane across that
    edge (a convex solid's signed distance is the largest of its planes'): beyond the edge
    the face's plane is not the surface. The lattice samples are evaluated by
    `icefarm.stages.surface.coat_kernel.band_phi`.

    Parameters
    ----------
    samples : BandSamples
        The surface samples, with their kind, thickness, depth and sharp edges.
    lattice : BandLattice
        The lattice's spacing, the reach and taper of the coat, the parameter named in errors.
    rim : optional
        The edges between the wet faces and the dry ones (``coat._Rim``: segments with
        their thickness, and a tree of points along them); None: no taper.
    features : PointTree, optional
        Points along creases and changes of kind (`coat_kernel.point_tree`); None: there
        are none.
    sole : (v, 3) float
        Excluded vertices, in meters: the coat ends in a wall between them and wet samples.

    Returns
    -------
    Field or None
        Level 1, inside where the value is above it; None where no tile is near the coat.

    Raises
    ------
    InputError
        A voxel so fine that the band would hold more than ``MAX_BAND_POINTS`` lattice
        samples, or its field need more than ``_MAX_FIELD_BYTES``.
    """
    voxel, reach, pts = lattice.voxel, lattice.reach, samples.points
    blocked = np.concatenate([pts[samples.kind == -1], sole])
    pad = BLOCK * voxel + reach  # the lattice's first block stays empty (see _halo_blocks)
    # Off the round coordinates by a fraction of a voxel: faces of boxes and prisms then
    # never lie on lattice planes (samples exactly on the iso-surface).
    origin = (np.floor((pts.min(axis=0) - pad) / (BLOCK * voxel)) - _SHIFT) * (BLOCK * voxel)
    coarse = _coarse_tiles(samples, lattice, origin)
    threads = os.cpu_count() or 1
    with ThreadPoolExecutor(threads) as pool:  # the kernels run without the GIL
        walls = pool.submit(_wall_args, pts, samples.kind == 1, blocked, reach)
        tree = point_tree(pts)
        band = _refine(pool, threads, tree, samples, lattice, origin, coarse, rim, features)
        npoints = len(band.tiles) * _TILE**3
        if npoints > MAX_BAND_POINTS or npoints * 4 > _MAX_FIELD_BYTES:
            raise InputError(
                f"{lattice.name} = {voxel:g} m is too fine for this much glaze ({npoints} lattice samples "
                f"near the coat, at most {MAX_BAND_POINTS}); raise {lattice.name}")
        thick = samples.thickness
        args = (pts, samples.normals, np.asarray(samples.kind, dtype=np.int64), thick.value, thick.slope, thick.low,
                thick.high, np.asarray(samples.depth, dtype=np.float64), tree.arrays(), *_edge_args(samples.edges),
                *_rim_args(rim, lattice.edge), *walls.result())
        values = _evaluate(pool, threads, band, lattice, origin, args)
    return _pack(band, values, origin, lattice)


def _coarse_tiles(samples: BandSamples, lattice: BandLattice, origin: np.ndarray):
    """The coarsest tiles (``_TILE * 2^_LEVELS`` lattice samples on an edge) within reach of
    a wet sample, each with bounds on the coat's thickness within reach of it (dry and
    excluded samples count as 0): tiles (m, 3) int64, least and greatest thickness (m,)
    in meters."""
    voxel, wet, thick = lattice.voxel, samples.kind == 1, samples.thickness
    size = _TILE * 2 ** _LEVELS
    k = int(math.ceil(lattice.reach / (size * voxel)))
    keys = block_keys(np.floor((samples.points - origin) / (size * voxel)).astype(np.int64))
    keys, t_lo, t_hi, has_wet = _reduce(keys, np.where(wet, thick.low, 0.0), np.where(wet, thick.high, 0.0), wet)
    for shift in (42, 21, 0):  # separable dilation by k tiles, one axis at a time
        step = np.arange(-k, k + 1) << shift
        keys, t_lo, t_hi, has_wet = _reduce((keys[:, None] + step[None, :]).ravel(), *(
            np.repeat(a, len(step)) for a in (t_lo, t_hi, has_wet)))
    keys, t_lo, t_hi = keys[has_wet], t_lo[has_wet], t_hi[has_wet]
    if len(keys) * size**3 > 8 * MAX_BAND_POINTS:
        raise InputError(
            f"{lattice.name} = {voxel:g} m is too fine for this much glaze ({len(keys) * size**3} lattice "
            f"samples within reach of the coat); raise {lattice.name}")
    tiles = np.stack([keys >> 42, (keys >> 21) & (2**21 - 1), keys & (2**21 - 1)], axis=1)
    return tiles, t_lo, t_hi


def _refine(pool, threads, tree, samples: BandSamples, lattice: BandLattice, origin, coarse, rim, features) -> _Tiles:
    """Level by level from the ``coarse`` tiles (`_coarse_tiles`) down to ``_TILE``, tiles
    are dropped where their centre says none of their samples is within a voxel of the
    coat, kept whole where it says all are more than a voxel inside it, and split in eight
    otherwise."""
    voxel, reach, h = lattice.voxel, lattice.reach, lattice.spacing
    pts, normals, edges = samples.points, samples.normals, samples.edges
    inner, inner_lo = float(samples.depth.max()), float(samples.depth.min())
    tiles, t_lo, t_hi = coarse
    size = _TILE * 2 ** _LEVELS
    children = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    solid = []
    seed = None
    while True:
        half = 0.5 * math.sqrt(3) * (size - 1) * voxel
        centre = origin + (tiles * size + 0.5 * (size - 1)) * voxel
        # Below the coarsest level, a parent's nearest sample bounds its eight children's.
        dist, idx = tree.nearest(centre, reach + half) if seed is None else \
            _in_tiles(pool, threads, tree, centre, seed, reach + half)
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
            break
        size //= 2
        seed = idx[keep]
        tiles = (2 * tiles[:, None, :] + children[None]).reshape(-1, 3)
        t_lo, t_hi = np.repeat(t_lo, 8), np.repeat(t_hi, 8)
    shared, seg = _share(samples, lattice, centre[keep], dist[keep], idx[keep], rim, features)
    return _Tiles(tiles, idx[keep], shared, seg,
                  np.concatenate(solid) if solid else np.zeros((0, 3), dtype=tiles.dtype))


def _share(samples: BandSamples, lattice: BandLattice, centre, dist, idx, rim, features):
    """Which of the finest tiles (``centre`` (m, 3), its nearest surface sample ``idx``
    (-1: none) at ``dist``, meters) share that sample, and the rim segment that shared dry
    tiles share (-1: none)."""
    half = 0.5 * math.sqrt(3) * (_TILE - 1) * lattice.voxel
    h = lattice.spacing
    # A tile's samples share its centre's nearest surface sample where no crease or change
    # of kind comes near enough to give any of them another (their nearest lies within
    # dist + 2 half of the centre).
    shared = idx >= 0
    if features is not None and shared.any():
        shared[shared] = ~features.any_within(centre[shared], dist[shared] + 2.0 * half + h)
    # Shared dry tiles share the rim segment nearest to their centre too.
    seg = np.full(len(centre), -1, dtype=np.int64)
    dry = shared & (samples.kind[np.maximum(idx, 0)] == 0)
    if rim is not None and dry.any():
        pts, normals = samples.points, samples.normals
        c, j = centre[dry], idx[dry]
        foot = c - np.einsum("kd,kd->k", c - pts[j], normals[j])[:, None] * normals[j]
        seg[dry] = rim.query(foot, lattice.edge + 2.0 * half)
    return shared, seg


def _evaluate(pool, threads, band: _Tiles, lattice: BandLattice, origin, args) -> np.ndarray:
    """The field's values (float32, ``_TILE^3`` per tile in tile order) of ``band``'s tiles:
    `band_phi` with the surface's ``args``, in chunks on ``pool``."""
    voxel, h, tiles = lattice.voxel, lattice.spacing, band.tiles
    half = 0.5 * math.sqrt(3) * (_TILE - 1) * voxel
    o = np.arange(_TILE)
    local = np.stack(np.meshgrid(o, o, o, indexing="ij"), axis=-1).reshape(-1, 3)
    per = _TILE**3
    values = np.empty(len(tiles) * per, dtype=np.float32)

    def evaluate(lo: int, hi: int) -> None:
        p = origin + (tiles[lo:hi, None, :] * _TILE + local[None]).reshape(-1, 3) * voxel
        # Where the surface is flat around a tile, its samples share the centre's nearest
        # surface sample (the same plane: the same distance); elsewhere each finds its own.
        phi = band_phi(p, per, band.nearest[lo:hi], band.shared[lo:hi], band.seg[lo:hi], lattice.reach, 0.6 * h,
                       0.6 * h + half, TAPER_END * voxel, *args)
        values[lo * per:hi * per] = _encode(phi, voxel)

    chunk = max(1, min(_CHUNK_POINTS // per, -(-len(tiles) // threads)))
    list(pool.map(lambda lo: evaluate(lo, min(lo + chunk, len(tiles))), range(0, len(tiles), chunk)))
    return values


def _pack(band: _Tiles, values: np.ndarray, origin: np.ndarray, lattice: BandLattice) -> Field | None:
    """The tiles' ``values`` (`_evaluate`) and the solid tiles as a `Field` (None: no tiles)."""
    voxel, tiles = lattice.voxel, band.tiles
    if len(band.solid):  # more than a voxel inside: any value above the level marches the same
        tiles = np.concatenate([tiles, band.solid])
        values = np.r_[values, np.full(len(band.solid) * _TILE**3, _encode(np.array([voxel]), voxel)[0])]
    if len(tiles) == 0:
        return None
    # Tiles into blocks (block_keys order); absent tiles of a block stay 0 (outside).
    per = BLOCK // _TILE
    bc = tiles // per
    keys = block_keys(bc)
    ukeys, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    if len(ukeys) * BLOCK**3 * 4 > _MAX_FIELD_BYTES:
        raise InputError(
            f"{lattice.name} = {voxel:g} m is too fine for this much glaze: its field needs "
            f"{len(ukeys) * BLOCK**3 * 4 / 2**30:.1f} GiB (at most {_MAX_FIELD_BYTES / 2**30:.0f}); "
            f"raise {lattice.name}")
    blocks = bc[first]
    out = np.zeros((len(ukeys), BLOCK, BLOCK, BLOCK), dtype=np.float32)
    t_in = tiles - bc * per
    vals = values.reshape(len(tiles), _TILE, _TILE, _TILE)
    o = np.arange(_TILE)
    ix = t_in[:, 0, None] * _TILE + o[None, :]
    iy = t_in[:, 1, None] * _TILE + o[None, :]
    iz = t_in[:, 2, None] * _TILE + o[None, :]
    out[inverse.reshape(-1)[:, None, None, None], ix[:, :, None, None], iy[:, None, :, None],
        iz[:, None, None, :]] = vals
    return Field(origin.astype(np.float64), voxel, 1.0, blocks.astype(np.int64), out)


def _in_tiles(pool, threads, tree, centre, seed, upper):
    """`PointTree.nearest_in_tiles` of tiles of eight ``centre`` points (``seed``: one per
    tile), in ``threads`` chunks on ``pool``."""
    step = max(1, -(-len(seed) // threads))  # tiles a chunk
    parts = list(pool.map(lambda t: tree.nearest_in_tiles(centre[8 * t:8 * (t + step)], seed[t:t + step], 8, upper),
                          range(0, len(seed), step)))
    if not parts:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _empty_tree():
    """`PointTree.arrays` of a tree that finds nothing (for `band_phi`'s unused trees)."""
    return (np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.full((2, 3), np.inf), np.full((2, 3), -np.inf), 1)


def _edge_args(edges: Edges | None):
    if edges is None:
        return False, np.full(1, -1, dtype=np.int64), np.zeros((1, 3, 3)), np.zeros((1, 3)), np.zeros((1, 3, 3)), \
            np.zeros((1, 3))
    return (True, np.asarray(edges.row, dtype=np.int64), edges.inward, edges.level, edges.across,
            edges.across_level)


def _rim_args(rim, edge: float):
    if rim is None:
        z = np.zeros((1, 3))
        return False, _empty_tree(), np.zeros(1, dtype=np.int64), z, z, np.zeros(1), np.zeros(1), z, float(edge)
    return (True, rim.tree.arrays(), np.asarray(rim.seg, dtype=np.int64), rim.a, rim.b, rim.ta, rim.tb,
            rim.normal, float(edge))


def _wall_args(pts: np.ndarray, wet: np.ndarray, blocked: np.ndarray, reach: float):
    """Between wet and excluded samples (and the excluded vertices) the coat ends in a wall:
    the wet samples' rows and tree, the excluded ones' tree and their box widened by
    ``reach`` (only points in it can have one within reach)."""
    if len(blocked) == 0:
        return False, np.zeros(1, dtype=np.int64), _empty_tree(), _empty_tree(), np.zeros(3), np.zeros(3)
    wet_tree = point_tree(pts[wet])
    return (True, np.flatnonzero(wet), wet_tree.arrays() if wet_tree is not None else _empty_tree(),
            point_tree(blocked).arrays(), blocked.min(axis=0) - reach, blocked.max(axis=0) + reach)


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


def _encode(phi: np.ndarray, voxel: float) -> np.ndarray:
    """Field values whose ``** MARCH_POWER`` is linear in ``phi`` around the level 1."""
    ramp = _RAMP * voxel
    low = CUTOFF**MARCH_POWER  # march clamps the field at CUTOFF * level (level 1)
    g = np.clip(1.0 + phi / ramp, low, 2.0)
    return (g ** (1.0 / MARCH_POWER)).astype(np.float32)
