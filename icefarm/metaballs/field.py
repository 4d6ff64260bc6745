"""The summed field of Gaussian metaballs, sampled on the sparse blocks of a lattice.

The metaballs are Gaussian (Blinn's blobby model): the one kernel that is both radial
and separable. Separability turns the field of a block of ``B^3`` samples into a matrix
product over the balls touching that block, so evaluation runs in BLAS, and only in the
blocks that balls reach (a sparse block grid: memory and time follow the ice, not its
bounding box). Each sample is computed once, by the block that owns it; a block marches
its cells with its upper neighbours' first samples as a halo, so blocks can never
disagree on a shared sample and the mesh closes across seams.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import ragged_arange
from .balls import LEVEL, Balls

# Each ball is cut off where its field falls below this fraction of LEVEL.
CUTOFF = 1e-3
# Samples (and cells) per block edge.
BLOCK = 16
# Most balls in one matrix product (see _block_fields).
_SEGMENT = 64
# Floats in one stacked product of block fields (small enough to stay in a core's L2
# cache: faster than batches of 4M).
_FIELD_BATCH = 500_000
# Refuse voxel sizes whose field (float32 over the blocks the balls reach) needs more,
# or that pair balls with more blocks than this (about 100 bytes each on the way).
_MAX_FIELD_BYTES = 2 * 2**30
_MAX_PAIRS = 10_000_000


@dataclass(frozen=True)
class Field:
    """Summed metaball field sampled on the blocks of a lattice that the balls reach.

    Lattice sample ``i`` (3 ints) lies at ``origin + i * voxel`` (meters); block ``b`` holds
    the samples ``b * B .. b * B + B - 1``; samples of absent blocks are zero.

    Attributes
    ----------
    origin : (3,) float64
    voxel : float
    level : float
    blocks : (k, 3) int64
        In `block_keys` order.
    values : (k, B, B, B) float32
    """

    origin: np.ndarray
    voxel: float
    level: float
    blocks: np.ndarray
    values: np.ndarray


def sample_field(balls: Balls, voxel: float, level: float = LEVEL, block: int = BLOCK,
                 name: str = "surface.voxel_size") -> Field | None:
    """The field of ``balls`` on the blocks of the ``voxel`` lattice that they reach.

    See `polygonize`, which marches it; `fuse_fields` unites two of them.

    Returns
    -------
    Field or None
        None when no ball is left after the cut-off.

    Raises
    ------
    InputError
        A voxel too fine for the extent of the balls (``name`` is the parameter to raise).
    """
    keep = balls.weights > CUTOFF * level
    c, s, w = balls.centers[keep], balls.widths[keep], balls.weights[keep]
    if len(w) == 0:
        return None
    ext = s * np.sqrt(np.log(w / (CUTOFF * level)))
    origin = (np.floor(((c - ext[:, None]) / voxel).min(axis=0)) - 1) * voxel
    q = (c - origin) / voxel  # lattice coordinates, >= 1 inside every ball's reach
    sl, el = s / voxel, ext / voxel
    lo = np.ceil(q - el[:, None]).astype(np.int64)
    hi = np.floor(q + el[:, None]).astype(np.int64)
    # Refuse before allocating: (ball, block) pairs bound the work, blocks the field's memory.
    npairs = int(((hi // block - lo // block + 1)).prod(axis=1).sum())
    if npairs > _MAX_PAIRS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much ice ({npairs} ball-block "
            f"pairs to evaluate, at most {_MAX_PAIRS}); raise {name}")
    ball, bc, starts, counts = _ball_block_pairs(q, el, lo, hi, block)
    nbytes = len(starts) * block**3 * 4
    if nbytes > _MAX_FIELD_BYTES:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much ice: its field needs "
            f"{nbytes / 2**30:.1f} GiB (at most {_MAX_FIELD_BYTES / 2**30:.0f}); raise {name}")
    g = _axis_gaussians(q, sl, w, ball, bc, block)
    own = _block_fields(g, starts, counts, block)
    del g
    return Field(origin, voxel, level, bc[starts], own)


def _ball_block_pairs(q, el, lo, hi, block):
    """Every (ball, block) pair whose block the ball's cut-off sphere reaches, by block.

    Block ``b`` owns the samples ``b * block .. b * block + block - 1`` on each axis.

    Returns
    -------
    ball : (p,) int
    bc : (p, 3) int
        Block coordinates.
    starts, counts : (blocks,) int
        Pairs of each distinct block (in lexicographic order), in ``ball``/``bc`` order.
    """
    blo, bhi = lo // block, hi // block
    nbl = (bhi - blo + 1).astype(np.int32)
    per_ball = nbl.prod(axis=1)
    ball = np.repeat(np.arange(len(q), dtype=np.int32), per_ball)
    k = ragged_arange(per_ball, dtype=np.int32)
    nb = nbl[ball]
    bc = np.empty((len(ball), 3), dtype=np.int32)
    bc[:, 2] = k % nb[:, 2]
    k //= nb[:, 2]
    bc[:, 1] = k % nb[:, 1]
    bc[:, 0] = k // nb[:, 1]
    bc += blo.astype(np.int32)[ball]
    # Drop blocks that only the corners of a ball's box reach (outside its cut-off sphere).
    dist2 = np.zeros(len(ball), dtype=np.float32)
    for a in range(3):
        qa = q[:, a].astype(np.float32)[ball]
        first = (bc[:, a] * block).astype(np.float32)
        gap = np.maximum(np.maximum(first - qa, qa - (first + (block - 1))), 0.0)
        dist2 += gap * gap
    reach = dist2 <= (el.astype(np.float32) ** 2)[ball]
    ball, bc = ball[reach], bc[reach]
    key = block_keys(bc)
    order = np.argsort(key, kind="stable")
    key, ball, bc = key[order], ball[order], bc[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, len(key)])
    return ball, bc.astype(np.int64), starts, counts


def block_grid(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A dense grid of indices into ``blocks`` (k, 3) over their bounding box and one block
    more all round, -1 where there is none (the border included): ``(grid, first)``, the
    block coordinates of ``grid[0, 0, 0]`` in ``first``. A lookup by grid instead of by
    sorted `block_keys`: one gather per point, no binary search."""
    first = blocks.min(axis=0) - 1
    grid = np.full(tuple(blocks.max(axis=0) - first + 2), -1, dtype=np.int64)
    b = blocks - first
    grid[b[:, 0], b[:, 1], b[:, 2]] = np.arange(len(b))
    return grid, first


def values_at(field: Field, samples: np.ndarray) -> np.ndarray:
    """``(n,) float32``: ``field``'s values at lattice samples ``samples`` (n, 3) int, 0 where
    no block holds them."""
    block = field.values.shape[1]
    grid, first = block_grid(field.blocks)
    flat = np.zeros(len(samples), dtype=np.int64)
    for k, stride in enumerate((grid.shape[1] * grid.shape[2], grid.shape[2], 1)):
        # a block off the grid lands on its border (none there)
        flat += np.clip(samples[:, k] // block - first[k], 0, grid.shape[k] - 1) * stride
    i = grid.ravel()[flat]
    out = np.zeros(len(samples), dtype=field.values.dtype)
    ok = np.flatnonzero(i >= 0)
    r = samples[ok] % block
    out[ok] = field.values[i[ok], r[:, 0], r[:, 1], r[:, 2]]
    return out


def block_keys(bc):
    """One sortable int64 per block coordinate (k, 3) (coordinates are >= 0 and < 2^20)."""
    bc = np.asarray(bc, dtype=np.int64)
    return (bc[:, 0] << 42) | (bc[:, 1] << 21) | bc[:, 2]


def _axis_gaussians(q, sl, w, ball, bc, block):
    """Per pair and axis, the ball's 1-D Gaussian over the block's samples; the weight goes
    into x.

    Every sample belongs to exactly one block, so no sample can get two different values:
    a ball's tail simply ends at the blocks its cut-off sphere reaches.

    Returns
    -------
    g : three (block, pairs + 1) float32
        With a last zero column (padding for `_block_fields`).
    """
    j = np.arange(block, dtype=np.float32)[:, None]
    inv = (1.0 / sl[ball]).astype(np.float32)
    g = []
    for a in range(3):
        out = np.zeros((block, len(ball) + 1), np.float32)
        v = out[:, :-1]
        # (first sample of the block + j - centre) / width
        np.multiply(j, inv[None, :], out=v)
        v += ((bc[:, a] * block - q[ball, a]) * inv).astype(np.float32)[None, :]
        np.multiply(v, v, out=v)
        np.negative(v, out=v)
        np.exp(v, out=v)
        if a == 0:
            v *= w[ball].astype(np.float32)[None, :]
        g.append(out)
    return g


def _block_fields(g, starts, counts, block):
    """Field of every block's samples from the 1-D Gaussians of its balls.

    Blocks with about the same number of balls go through one stacked matrix product
    ``F[b, (x, y), z] = sum_n gx[b, x, n] gy[b, y, n] gz[b, n, z]``, in segments of at
    most ``_SEGMENT`` balls (OpenBLAS threads stall on long thin products here).

    Parameters
    ----------
    g : three (block, pairs + 1) float32
        Per axis, each pair's 1-D Gaussian over its block; the last column is 0.
    starts, counts : (blocks,) int
        Each block's pairs are ``starts[b] : starts[b] + counts[b]``.
    block : int

    Returns
    -------
    (blocks, block, block, block) float32
    """
    dummy = g[0].shape[1] - 1
    out = np.empty((len(starts), block, block, block), np.float32)
    flat_out = out.reshape(len(starts), -1)
    # Split each block's balls into the fewest segments of at most _SEGMENT, each padded
    # to a multiple of 4; blocks with the same segments share one product.
    nseg = np.maximum(-(-counts // _SEGMENT), 1)
    segs = 4 * -(-counts // (4 * nseg))
    shape = nseg * (_SEGMENT + 1) + segs  # sorts by (segments, segment length)
    by_count = np.argsort(shape, kind="stable")
    sorted_shape = shape[by_count]
    batches = []
    i = 0
    while i < len(by_count):
        j = int(np.searchsorted(sorted_shape, sorted_shape[i], side="right"))
        j = min(j, i + max(1, _FIELD_BATCH // (block * block * int(nseg[by_count[i]] * segs[by_count[i]]))))
        batches.append(by_count[i:j])
        i = j

    def fill(blk: np.ndarray) -> None:
        seg = int(segs[blk[0]])
        pad = int(nseg[blk[0]]) * seg
        lane = np.arange(pad)
        idx = np.where(lane < counts[blk, None], starts[blk, None] + lane, dummy).reshape(-1, seg)
        gx, gy, gz = (gi[:, idx].transpose(1, 0, 2) for gi in g)  # (blocks * segments, B, seg)
        xy = (gx[:, :, None, :] * gy[:, None, :, :]).reshape(len(idx), block * block, seg)
        f = np.matmul(xy, gz.transpose(0, 2, 1)).reshape(len(blk), pad // seg, -1)
        flat_out[blk] = f[:, 0] if pad == seg else f.sum(axis=1)

    # NumPy leaves the GIL in the gathers, products and matrix products: batches (each
    # writing its own blocks) fill on every core.
    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, len(batches)))) as pool:
        list(pool.map(fill, batches))
    return out
