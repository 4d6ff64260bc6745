"""Where `icefarm.metaballs.fuse_fields` must run the boolean union: the samples of one
field's lattice whose cells may meet the other field's surface.

A region is kept per block of the field (`Region`), by tiles of ``tile^3`` samples, so that
it can be as fine as a sample on a lattice of millions of blocks' extent. Two ways find it:

* `surface_region`, from the cells of the other lattice that hold the other surface (the
  four around each of its vertices' lattice edges): tight; for a mesh united before, from
  the vertices its field marched (the others lie away from this surface);
* `near_region`, from the distance to the other surface's vertices (`margin`): for a
  surface none of whose vertices are on its lattice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from ..compiled import compiled
from .field import Field, block_grid

# Most tiles (or cells of the other lattice) in a dense grid built to find a region.
_MAX_TILES = 2**22
# Lattice coordinates within this many samples of an integer count as on it.
_EPS = 1e-6


@dataclass(frozen=True)
class Region:
    """Samples of a field's lattice, by tiles of ``tile^3`` samples.

    Attributes
    ----------
    mask : (k, p, p, p) bool
        Per block of the field (``field.blocks`` order), its tiles in the region; p = B / tile.
    tile : int
    index : (bx, by, bz) int64
        Dense grid of block indices over the field's blocks, -1 where there is none (all
        round its border).
    first : (3,) int64
        Block coordinates of ``index[0, 0, 0]``.
    """

    mask: np.ndarray
    tile: int
    index: np.ndarray
    first: np.ndarray

    @cached_property
    def busy_blocks(self) -> np.ndarray:
        """(k,) bool: the blocks with a tile in the region (the blocks `restrict` keeps)."""
        return self.mask.reshape(len(self.mask), -1).any(axis=1)

    def holds(self, samples: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each lattice sample (n, 3) int keeps its value when the field
        is restricted to the region (`restrict`): it lies in the region, or in no block of
        the field (zero either way)."""
        per = self.mask.shape[1]
        block = per * self.tile
        # Block and tile by shifts (powers of two), column by column; a block off the grid
        # lands on its border.
        shape = self.index.shape
        flat = np.zeros(len(samples), dtype=np.int64)
        for k, stride in enumerate((shape[1] * shape[2], shape[2], 1)):
            flat += np.clip((samples[:, k] >> _log2(block)) - self.first[k], 0, shape[k] - 1) * stride
        i = self.index.ravel()[flat]
        out = i < 0
        # Only samples in blocks with tiles in the region need their tile's answer.
        busy = np.flatnonzero(self.busy_blocks[np.maximum(i, 0)] & ~out)
        s = samples[busy] & (block - 1)
        t = i[busy] * per**3
        for k, stride in enumerate((per * per, per, 1)):
            t += (s[:, k] >> _log2(self.tile)) * stride
        out[busy] = self.mask.reshape(-1)[t]
        return out


def _log2(n: int) -> int:
    if n & (n - 1):
        raise ValueError(f"block and tile sizes must be powers of two, not {n}")
    return n.bit_length() - 1


def margin(field: Field, other: Field) -> float:
    """How far the cells of ``field`` left out of the union must lie from ``other``'s
    vertices.

    A point of the other surface lies within one of its voxels of a vertex of it (a
    marching-cubes triangle fits in a cell), and a cell spans one cell diagonal, so a cell
    with a sample this far from the other's vertices stays more than half of the other's
    cell diagonal off the other surface: out of its reach, and on the side of it that the
    nearest sample of the other field says (`icefarm.metaballs.fuse._inside`).
    """
    return 1.05 * (math.sqrt(3) * field.voxel + (1 + 0.5 * math.sqrt(3)) * other.voxel)


def surface_region(field: Field, other: Field, other_lattice: np.ndarray) -> Region | None:
    """Every sample of every cell of ``field`` that meets a cell of ``other``'s lattice its
    surface runs through; None where the grids it needs would be too big.

    Each vertex of the other surface lies on an edge of its lattice (``other_lattice``, in
    the other's sample units), in the four cells around it (eight at a lattice point), and
    every face lies in a cell around its vertices: the union of those cells holds the other
    surface. A cell of ``field`` that meets none of them lies wholly on one side of it, and
    the nearest samples of the other field to its points are corners of other cells it meets,
    all on that side (`icefarm.metaballs.fuse._inside`).

    `near_region`'s margin must allow for a cell in any direction around each vertex. On
    Table 2's dragon (row c, coat cells four times the icicles'), this region puts 59 k of the
    icicles' faces in the union instead of 153 k, and 6.5 k of the coat's instead of 26 k;
    manifold3d is handed 131 k faces instead of 196 k (more of them caps), and
    `icefarm.metaballs.fuse_fields` runs about a tenth faster (medians of three alternated
    rounds of four), giving the same mesh to 3e-9 m.

    Parameters
    ----------
    field, other : Field
    other_lattice : (n, 3) float
        The other surface's vertices in the other's lattice coordinates, all finite.
    """
    lo = np.floor(other_lattice - _EPS)
    hi = np.floor(other_lattice + _EPS) + 1.0
    if other.voxel > 2.01 * field.voxel:
        return _coarse_cells(field, other, lo.astype(np.int64), hi.astype(np.int64))
    box_lo = other.origin + lo * other.voxel
    box_hi = other.origin + hi * other.voxel
    return _boxes(field, box_lo, box_hi)


def near_region(field: Field, points: np.ndarray, reach: float) -> Region | None:
    """Tiles of ``field``'s lattice within ``reach`` (meters) of any of ``points`` (k, 3)
    (some a little farther are in too); None where the grid would be too big."""
    block = field.values.shape[1]
    # Tiles about half the reach: finer ones make bigger grids, coarser ones wider regions.
    grid = _grid(field, reach / (2 * field.voxel), reach / field.voxel)
    if grid is None:
        return None
    lo, shape, tile = grid
    k = int(math.ceil(reach / (tile * field.voxel)))
    t = np.floor((points - field.origin) / (field.voxel * tile)).astype(np.int64) - lo
    t = t[((t >= 0) & (t < shape)).all(axis=1)]
    occupied = np.zeros(tuple(shape), dtype=np.uint8)
    occupied[t[:, 0], t[:, 1], t[:, 2]] = 1
    # A tile j tiles away from a point's tile is at least (j - 1) tile edges away from it.
    dense = ndimage.maximum_filter(occupied, size=2 * k + 1, mode="constant") > 0
    return _from_dense(field, dense, lo, tile, block)


def _grid(field: Field, finest: float, pad: float):
    """The finest tile (samples, dividing the block, over ``finest / 2``) whose dense grid
    over ``field``'s blocks, their empty neighbours and ``pad`` samples each way holds at
    most `_MAX_TILES` tiles: (lo, shape, tile), or None."""
    block = field.values.shape[1]
    finest = min(finest, block)
    for tile in (t for t in range(1, block + 1) if block % t == 0 and 2 * t > finest):
        per = block // tile
        k = int(math.ceil(pad / tile))
        lo = (field.blocks.min(axis=0) - 1) * per - k  # from the (empty) lower neighbours' tiles
        shape = (field.blocks.max(axis=0) + 2) * per + k - lo
        if int(np.prod(shape)) <= _MAX_TILES:
            return lo, shape, tile
    return None


def _from_dense(field: Field, dense: np.ndarray, lo, tile: int, block: int) -> Region:
    per = block // tile
    first = field.blocks * per - lo
    o = np.arange(per)
    mask = dense[first[:, 0, None, None, None] + o[:, None, None],
                 first[:, 1, None, None, None] + o[None, :, None],
                 first[:, 2, None, None, None] + o[None, None, :]]
    return Region(mask, tile, *block_grid(field.blocks))


def _cell_range(field: Field, box_lo: np.ndarray, box_hi: np.ndarray):
    """First and last samples (int) of the cells of ``field`` that meet each box (closed:
    touching counts)."""
    s_lo = np.ceil((box_lo - field.origin) / field.voxel - _EPS).astype(np.int64) - 1
    s_hi = np.floor((box_hi - field.origin) / field.voxel + _EPS).astype(np.int64) + 1
    return s_lo, s_hi


def _boxes(field: Field, box_lo: np.ndarray, box_hi: np.ndarray) -> Region | None:
    """The samples of ``field``'s cells that meet any of the boxes (k, 3) (meters), on a
    dense grid of tiles: each box marked by +-1 at its corners, summed along each axis."""
    block = field.values.shape[1]
    grid = _grid(field, 1.0, 0.0)
    if grid is None:
        return None
    lo, shape, tile = grid
    s_lo, s_hi = _cell_range(field, box_lo, box_hi)
    t_lo = np.maximum(s_lo // tile - lo, 0)
    t_hi = np.minimum(s_hi // tile - lo, shape - 1)
    ok = (t_lo <= t_hi).all(axis=1)
    t_lo, t_hi = t_lo[ok], t_hi[ok]
    return _from_dense(field, _union_of_boxes(t_lo, t_hi, shape), lo, tile, block)


def _union_of_boxes(lo: np.ndarray, hi: np.ndarray, shape) -> np.ndarray:
    """A dense bool grid of ``shape`` with the boxes ``lo`` .. ``hi`` (k, 3), inclusive and
    within the grid, marked: +-1 at each box's corners, summed along each axis (boxes at
    most three cells wide: `_mark_boxes`, a fifth of the time on Table 2's dragon)."""
    if len(lo) == 0 or (hi - lo).max() <= 2:
        return _mark_boxes(lo, hi - lo, shape)
    size = np.asarray(shape) + 1
    count = np.zeros(int(np.prod(size)), dtype=np.int32)
    for corner in np.ndindex(2, 2, 2):
        at = np.where(np.array(corner, dtype=bool), hi + 1, lo)
        flat = np.bincount(np.ravel_multi_index(at.T, size), minlength=len(count)).astype(np.int32)
        count += -flat if sum(corner) % 2 else flat
    count = count.reshape(size)
    for axis in range(3):
        np.cumsum(count, axis=axis, out=count)
    return count[:-1, :-1, :-1] > 0


def _mark_boxes(lo: np.ndarray, span: np.ndarray, shape) -> np.ndarray:
    """A dense bool grid of ``shape`` with the boxes ``lo`` .. ``lo + span`` (k, 3),
    inclusive and within the grid, marked cell by cell (for boxes a few cells wide)."""
    stride = (shape[1] * shape[2], shape[2], 1)
    flat = lo[:, 0] * stride[0] + lo[:, 1] * stride[1] + lo[:, 2]
    out = np.zeros(int(np.prod(shape)), dtype=bool)
    out[flat] = True
    wide = int(span.max(initial=0)) + 1
    reach = [[None] + [span[:, a] >= d for d in range(1, wide)] for a in range(3)]
    for step in list(np.ndindex(wide, wide, wide))[1:]:
        sel = None
        for a, d in enumerate(step):
            if d:
                sel = reach[a][d] if sel is None else sel & reach[a][d]
        out[flat[sel] + (step[0] * stride[0] + step[1] * stride[1] + step[2])] = True
    return out.reshape(tuple(shape))


def _coarse_cells(field: Field, other: Field, lo: np.ndarray, hi: np.ndarray) -> Region:
    """`surface_region` where the other's cells are at least twice ``field``'s: the other
    cells ``lo`` .. ``hi`` - 1 (k, 3) (integer, its sample units) go on a dense grid of the
    other's cells, and each tile of ``field``'s blocks asks the one or two cells per axis its
    cells meet. Only blocks that meet a box of the other's cells are asked, a group at a
    time, each group's grid within `_MAX_TILES` cells (the 3 m house's icicle tips against its
    icicles' cells: 69 M cells over all its blocks)."""
    block = field.values.shape[1]
    ratio = other.voxel / field.voxel
    # The largest tile whose cells span at most two other cells per axis: (tile + 1) voxels.
    tile = max(t for t in range(1, block + 1) if block % t == 0 and t + 1.01 < ratio)
    per = block // tile
    grid, first = block_grid(field.blocks)
    mask = np.zeros((len(field.blocks), per, per, per), dtype=bool)
    pending = [(np.arange(len(field.blocks)), lo, hi, False)]
    while pending:
        blocks, lo, hi, whole = pending.pop()
        if len(blocks) == 0:
            continue
        # The other's cells over these blocks (and a little more: the grid's edges lie past them).
        bc = field.blocks[blocks]
        f_lo = field.origin + bc.min(axis=0) * block * field.voxel
        f_hi = field.origin + (bc.max(axis=0) + 1) * block * field.voxel
        g_lo = np.floor((f_lo - field.voxel - other.origin) / other.voxel).astype(np.int64) - 2
        g_hi = np.floor((f_hi + field.voxel - other.origin) / other.voxel).astype(np.int64) + 2
        shape = g_hi - g_lo
        if int(np.prod(shape)) > _MAX_TILES and len(blocks) > 1 and not whole:  # split at the median
            axis = int(np.argmax(shape))
            cut = np.median(bc[:, axis])
            left = bc[:, axis] <= cut
            if left.all():
                left = bc[:, axis] < cut
            if not left.any():  # all in one plane of blocks: no smaller group (cannot be long)
                pending.append((blocks, lo, hi, True))
                continue
            for side in (left, ~left):
                s_lo = field.origin[axis] + (bc[side, axis].min() * block - 1) * field.voxel
                s_hi = field.origin[axis] + ((bc[side, axis].max() + 1) * block + 1) * field.voxel
                near = (other.origin[axis] + hi[:, axis] * other.voxel >= s_lo) & \
                    (other.origin[axis] + lo[:, axis] * other.voxel <= s_hi)
                pending.append((blocks[side], lo[near], hi[near], False))
            continue
        c = lo - g_lo
        ok = np.ones(len(c), dtype=bool)
        for a in range(3):
            ok &= (c[:, a] >= 0) & (c[:, a] < shape[a] - 1)
        c = c[ok]
        cells = _mark_boxes(c, hi[ok] - g_lo - c - 1, shape).ravel()
        stride = np.array([shape[1] * shape[2], shape[2], 1])
        # Per axis and tile of each block: the other's cells its cells meet (one or two,
        # first and last).
        t = bc[:, :, None] * per + np.arange(per)[None, None, :]  # (k, 3, per) tile coords
        first_s = t * tile - 1  # the first sample of the tile's first cell ...
        last_s = t * tile + tile  # ... and the last of its last
        o = other.origin[None, :, None]
        c_lo = np.floor((field.origin[None, :, None] + first_s * field.voxel - o) / other.voxel - _EPS).astype(np.int64)
        c_hi = np.floor((field.origin[None, :, None] + last_s * field.voxel - o) / other.voxel + _EPS).astype(np.int64)
        c_lo -= g_lo[None, :, None]
        c_hi -= g_lo[None, :, None]
        # Each block's window of the other's cells; only blocks with a marked cell in it
        # (on the real-size bench, a quarter of the icicles' blocks), by a summed-area table
        # of the grid pooled 4 x 4 x 4 (the whole grid's costs more than the windows it saves) ...
        w0 = c_lo[:, :, 0]
        busy = np.flatnonzero(_held(cells, shape, w0, c_hi[:, :, -1] + 1) > 0)
        if len(busy) == 0:
            continue
        blocks, c_lo, c_hi, w0 = blocks[busy], c_lo[busy], c_hi[busy], w0[busy]
        # ... then the tiles' one or two cells ORed along x, y and z in turn (a third of the
        # gathers of asking all eight per tile).
        size = int((c_hi[:, :, -1] - w0).max()) + 1
        r = np.arange(size)
        ix, iy, iz = (np.minimum(w0[:, a, None] + r, shape[a] - 1) * stride[a] for a in range(3))
        part = cells[ix[:, :, None, None] + iy[:, None, :, None] + iz[:, None, None, :]]
        for a in range(3):
            at = [slice(None), None, None, None]
            at[a + 1] = slice(None)
            lo_a, hi_a = (c[:, a] - w0[:, a, None] for c in (c_lo, c_hi))
            part = np.take_along_axis(part, lo_a[tuple(at)], axis=a + 1) | \
                np.take_along_axis(part, hi_a[tuple(at)], axis=a + 1)
        mask[blocks] = part
    return Region(mask, tile, grid, first)


def _held(cells: np.ndarray, shape: np.ndarray, w0: np.ndarray, w1: np.ndarray) -> np.ndarray:
    """(k,) int: at least the marked cells of the grid ``cells`` (flat, bool, ``shape``)
    in each window ``w0`` .. ``w1`` - 1 (k, 3), 0 only where there are none, by a summed-area
    table of the grid pooled 4 x 4 x 4 (rounded out to whole pooled cells)."""
    q = 4  # (the uint32 view below needs 4)
    pooled_shape = -(-shape // q)
    padded = np.zeros(tuple(pooled_shape * q), dtype=bool)
    padded[:shape[0], :shape[1], :shape[2]] = cells.reshape(tuple(shape))
    # (four bools along z read as one uint32: numpy's any over a short axis is slow)
    pooled = (padded.reshape(-1, q).view(np.uint32).reshape(pooled_shape[0], q, pooled_shape[1], q,
                                                            pooled_shape[2]) != 0).any(axis=3).any(axis=1)
    table = np.zeros(tuple(pooled_shape + 1), dtype=np.int32)
    table[1:, 1:, 1:] = pooled.cumsum(axis=0, dtype=np.int32).cumsum(axis=1).cumsum(axis=2)
    p0, p1 = w0 // q, -(-w1 // q)
    held = np.zeros(len(w0), dtype=np.int64)
    for corner in np.ndindex(2, 2, 2):
        at = np.where(np.array(corner, dtype=bool), p1, p0)
        held += (-1 if (3 - sum(corner)) % 2 else 1) * table[at[:, 0], at[:, 1], at[:, 2]]
    return held


def inner_faces(lattice: np.ndarray, faces: np.ndarray, region: Region) -> np.ndarray:
    """Faces whose marching-cubes cell has all 8 samples in ``region`` (or in no block of
    the field: zero either way): marching the restricted field gives them bit for bit.

    A face's cell is the floor of its vertices' least coordinates, the same for all faces
    of a cell, so a cell's faces never split between the two sides of the seam. NaN lattice
    coordinates (a vertex of no marching of this field) put a face out of every region.
    Compiled: the face's cell and its 8 samples' tiles in one pass; on Table 2's dragon
    0.05 s per run against 0.15 s for NumPy's gathers, sample by sample (`Region.holds`,
    which the tests compare it with).
    """
    per = region.mask.shape[1]
    inner = np.zeros(len(faces), dtype=bool)
    _inner(np.ascontiguousarray(lattice, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64),
           region.mask.reshape(len(region.mask), -1), np.ascontiguousarray(region.index, dtype=np.int64),
           np.asarray(region.first, dtype=np.int64), _log2(per * region.tile), _log2(region.tile), per, inner)
    return inner


@compiled()
def _inner(lattice, faces, mask, index, first, block_shift, tile_shift, per, inner):
    block = 1 << block_shift
    for f in range(faces.shape[0]):
        cell = np.empty(3, dtype=np.int64)
        finite = True
        for a in range(3):
            low = np.inf
            for s in range(3):
                value = lattice[faces[f, s], a]
                finite &= np.isfinite(value)
                low = min(low, value)
            cell[a] = np.int64(np.floor(low)) if finite else 0
        if not finite:
            continue
        held = True
        for c in range(8):
            x, y, z = cell[0] + (c & 1), cell[1] + (c >> 1 & 1), cell[2] + (c >> 2 & 1)
            # the block (off the grid: its border, which has none) and, in it, the tile
            i = index[min(max((x >> block_shift) - first[0], 0), index.shape[0] - 1),
                      min(max((y >> block_shift) - first[1], 0), index.shape[1] - 1),
                      min(max((z >> block_shift) - first[2], 0), index.shape[2] - 1)]
            if i < 0:
                continue
            t = (((x & (block - 1)) >> tile_shift) * per + ((y & (block - 1)) >> tile_shift)) * per \
                + ((z & (block - 1)) >> tile_shift)
            if not mask[i, t]:
                held = False
                break
        inner[f] = held


def restrict(field: Field, region: Region):
    """``field``'s blocks that reach ``region``, with their samples outside it zeroed.

    Returns
    -------
    values : (k, B, B, B) float32
    blocks : (k, 3) int64
    """
    keep = region.busy_blocks
    mask = region.mask[keep]
    for axis in (1, 2, 3):
        mask = np.repeat(mask, region.tile, axis=axis)
    return field.values[keep] * mask, field.blocks[keep]
