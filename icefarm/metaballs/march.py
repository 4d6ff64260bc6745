"""Marching cubes over a sparse block field, welded into one watertight mesh."""

from __future__ import annotations

import math

import numpy as np
from skimage.measure import marching_cubes

from .balls import KAPPA, LEVEL, Balls
from .field import BLOCK, CUTOFF, block_keys, sample_field

# Marching cubes runs on field**MARCH_POWER (see polygonize).
MARCH_POWER = KAPPA**2 / 2
# Field samples closer than this (relative) to the level are pushed off it, so no
# marching-cubes vertex lands on a grid corner (which would make zero-area faces).
_NUDGE = 1e-3
# Floats in one batch of halo blocks for marching cubes: about 100 blocks, whose volume,
# mask and the marching's own buffers stay in cache. Table 2's dragon coat (736 blocks)
# marches 12-17 % faster than in batches of 4,000,000 (medians; 125,000 and 250,000 no
# better). Vertices inside a cell (a few of Lewiner's cases) are placed in
# single precision from the packed volume's origin, so they move by up to 8e-6 voxels
# with the batch: 267 of the coat's 590,478 faces.
_MARCH_BATCH = 500_000


def polygonize(balls: Balls, voxel: float, level: float = LEVEL, block: int = BLOCK,
               name: str = "surface.voxel_size"):
    """The iso-surface ``field == level`` of summed Gaussian metaballs, welded and watertight.

    The lattice is cut into blocks of ``block^3`` samples; the field is evaluated only in
    blocks that some ball reaches (each ball cut off where it falls below
    ``CUTOFF * level``), every sample exactly once, and is zero elsewhere. Each block whose
    cells the surface crosses gets its upper neighbours' first sample planes as a halo and
    goes, packed side by side with the cells between blocks masked out, through one
    marching-cubes call per batch; vertices on block seams are welded by lattice edge.

    Parameters
    ----------
    balls : Balls
    voxel : float
        Grid spacing, in meters.
    level : float
        Iso level.
    block : int
        Samples per block edge.
    name : str
        The parameter that set ``voxel``, named in the error messages.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound triangles (normals point to lower field).

    Raises
    ------
    InputError
        When the voxel is so fine that the field would need more than ``_MAX_FIELD_BYTES``
        or ``_MAX_PAIRS`` (ball, block) pairs.
    """
    field = sample_field(balls, voxel, level, block, name)
    if field is None:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    lattice, faces = march_blocks(field.values, field.blocks, level)
    return field.origin + lattice * voxel, faces


def march_blocks(values: np.ndarray, blocks: np.ndarray, level: float):
    """Marching cubes over block fields (blocks absent from ``blocks`` count as zero).

    Parameters
    ----------
    values : (k, B, B, B) float32
    blocks : (k, 3) int
        Block coordinates, in `block_keys` order.
    level : float

    Returns
    -------
    lattice : (n, 3) float64
        Vertices in lattice coordinates.
    faces : (m, 3) int64
        Welded across block seams, without degenerate faces.
    """
    block = values.shape[1]
    verts, faces, seams, nverts = [], [], [], 0
    if len(values):
        for fields, where in _halo_blocks(values, blocks, level):
            v, f, seam = _march_packed(_march_domain(fields, level), where, level**MARCH_POWER, block)
            verts.append(v)
            faces.append(f + nverts)
            seams.append(seam)
            nverts += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return _weld_lattice(np.concatenate(verts), np.concatenate(faces), block, np.concatenate(seams))


def face_estimate(field) -> int:
    """About how many faces `march_blocks` makes of ``field`` (a `icefarm.metaballs.Field`),
    without marching: twice the lattice edges the surface crosses (a closed mesh has about
    two faces per vertex, and marching cubes puts one vertex on each crossed edge), those
    across block seams included (an absent block is outside).

    Exact but for the few faces marching drops as degenerate (the real-size bench's
    icicles at 2.3 mm: 944,200 counted, 943,126 marched), in a twentieth of its time.
    """
    inside = field.values > field.level
    if len(inside) == 0:
        return 0
    crossed = sum(int(np.count_nonzero(np.diff(inside, axis=axis))) for axis in (1, 2, 3))
    keys = block_keys(field.blocks)
    for axis in range(3):
        step = np.zeros(3, dtype=np.int64)
        step[axis] = 1
        after = block_keys(field.blocks + step)
        j = np.minimum(np.searchsorted(keys, after), len(keys) - 1)
        last = np.take(inside, -1, axis=axis + 1)
        first = np.where((keys[j] == after)[:, None, None], np.take(inside, 0, axis=axis + 1)[j], False)
        crossed += int(np.count_nonzero(last != first))
    return 2 * crossed


def _march_domain(fields, level):
    """``fields ** MARCH_POWER`` in place, pushed at least ``_NUDGE`` (relative) off the level.

    Marching cubes interpolates linearly along cell edges; F^p with p = KAPPA^2 / 2 has its
    inflection at the surface of a chain, so there it is nearly exact. The nudge keeps every
    vertex off the grid corners (no zero-area faces) and, being a function of the one
    value each sample has, cannot make two blocks disagree on a shared sample.
    """
    np.maximum(fields, np.float32(CUTOFF * level), out=fields)
    np.log(fields, out=fields)
    fields *= np.float32(MARCH_POWER)
    np.exp(fields, out=fields)
    t_level = np.float32(level**MARCH_POWER)
    nudge = np.float32(_NUDGE * level**MARCH_POWER)
    near = np.abs(fields - t_level) < nudge
    fields[near] = np.where(fields[near] < t_level, t_level - nudge, t_level + nudge)
    return fields


def _halo_blocks(own, blocks, level):
    """Blocks of ``(B+1)^3`` samples (own samples plus the first planes of the upper
    neighbours, zero where a neighbour has no field) that the level crosses, in batches.

    A block without field of its own is marched too where an upper neighbour's first samples
    rise above the level (balls only a voxel or two wide reach the level next to the edge
    of their cut-off box).

    Yields
    ------
    fields : (k, B+1, B+1, B+1) float32
    blocks : (k, 3) int
        Block coordinates.
    """
    n, b = len(own), own.shape[1]
    keys = block_keys(blocks)  # sorted: blocks come from _ball_block_pairs
    offsets = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1))
    # A lower neighbour (face, edge or corner) without field still has cells to march where
    # our first plane, line or corner sample along its offset rises above the level.
    lower = []
    for off in offsets:
        first = own[(slice(None),) + tuple(0 if o else slice(None) for o in off)]
        high = first.reshape(n, -1).max(axis=1) > level
        lower.append(blocks[high] - np.array(off))
    extra = np.concatenate(lower)
    extra = extra[(extra >= 0).all(axis=1)]
    if len(extra):
        extra = np.unique(extra, axis=0)
        extra = extra[~np.isin(block_keys(extra), keys)]
    cand = np.concatenate([blocks, extra]) if len(extra) else blocks
    slot_self = np.r_[np.arange(n), np.full(len(cand) - n, -1)]

    def slot(offset):
        k = block_keys(cand + offset)
        i = np.minimum(np.searchsorted(keys, k), n - 1)
        return np.where(keys[i] == k, i, -1)

    parts = [((0, 0, 0), slot_self)] + [(off, slot(np.array(off))) for off in offsets]
    batch = max(1, _MARCH_BATCH // (b + 1) ** 3)
    for i in range(0, len(cand), batch):
        sl = slice(i, i + batch)
        halo = np.zeros((len(cand[sl]), b + 1, b + 1, b + 1), np.float32)
        for off, s in parts:
            rows = np.flatnonzero(s[sl] >= 0)
            if len(rows) == 0:
                continue
            # Along each offset axis the neighbour gives its first plane to our last one.
            target = tuple(b if o else slice(0, b) for o in off)
            source = tuple(0 if o else slice(0, b) for o in off)
            halo[(rows,) + target] = own[(s[sl][rows],) + source]
        flat = halo.reshape(len(halo), -1)
        cross = (flat.max(axis=1) > level) & (flat.min(axis=1) < level)
        if cross.any():
            yield halo[cross], cand[sl][cross]


def _march_packed(fields: np.ndarray, blocks: np.ndarray, level: float, block: int):
    """Marching cubes over halo blocks packed into one volume: lattice-coordinate vertices,
    faces, and whether each vertex lies on a seam plane (a block-local coordinate 0 or B)."""
    n = len(fields)
    n1 = block + 1
    px = int(math.ceil(n ** (1 / 3)))
    py = int(math.ceil(math.sqrt(n / px)))
    pz = int(math.ceil(n / (px * py)))
    pad = px * py * pz - n
    if pad:
        fields = np.concatenate([fields, np.zeros((pad, n1, n1, n1), dtype=np.float32)])
    vol = fields.reshape(px, py, pz, n1, n1, n1).transpose(0, 3, 1, 4, 2, 5).reshape(px * n1, py * n1, pz * n1)
    # Cells between two packed blocks must not march; skimage's mask[i] governs the cell
    # from sample i - 1 to i, so mask out each block's first sample plane.
    mx, my, mz = ((np.arange(p * n1) % n1) != 0 for p in (px, py, pz))
    mask = mx[:, None, None] & my[None, :, None] & mz[None, None, :]
    v, f, _, _ = marching_cubes(vol, level=level, mask=mask, gradient_direction="ascent")
    v = v.astype(np.float64)
    base = np.floor(v)
    cell = np.minimum(np.floor(v / n1).astype(np.int64), np.array([px, py, pz]) - 1)
    # Vertices on lattice edges again, in float64 from the edge's two samples and rounded
    # from block-local coordinates: an edge then gets the same bits whatever batch or
    # packing marched it (`fuse_fields` welds on them).
    frac = v - base
    # (column by column: numpy's reductions over rows of three are several times slower)
    moved = frac != 0
    edge = np.flatnonzero((moved[:, 0].view(np.uint8) + moved[:, 1] + moved[:, 2]) == 1)
    axis = np.where(moved[edge, 0], 0, np.where(moved[edge, 1], 1, 2))
    i0 = base[edge].astype(np.int64)
    i1 = i0.copy()
    i1[np.arange(len(edge)), axis] += 1
    g0 = vol[i0[:, 0], i0[:, 1], i0[:, 2]].astype(np.float64)
    g1 = vol[i1[:, 0], i1[:, 1], i1[:, 2]].astype(np.float64)
    frac[edge, axis] = np.clip((level - g0) / np.where(g1 != g0, g1 - g0, 1.0), 0.0, 1.0)
    # local = v - cell * n1, exactly (v = base + frac, and the difference is small)
    local = (base - cell * n1) + frac
    which = (cell[:, 0] * py + cell[:, 1]) * pz + cell[:, 2]
    seam = np.zeros(len(local), dtype=bool)
    for k in range(3):
        seam |= (local[:, k] == 0) | (local[:, k] == block)
    return blocks[which] * block + local, f.astype(np.int64), seam


def _weld_lattice(lattice: np.ndarray, faces: np.ndarray, block: int, on_seam: np.ndarray):
    """Merge the copies of vertices on block seams; drop degenerate faces.

    A marching-cubes vertex lies on a lattice edge (one fractional coordinate) or, for some
    of Lewiner's cases, inside a cell. Only edges in a seam plane (a coordinate that is a
    multiple of ``block``: ``on_seam`` (n,) bool) are marched by more than one block; their
    copies share the edge's key.
    """
    seam = np.flatnonzero(on_seam)
    if len(seam):
        index = np.arange(len(lattice))
        bs = np.floor(lattice[seam])
        fs = lattice[seam] - bs
        bs = bs.astype(np.int64)
        nfrac = (fs > 0).sum(axis=1)
        key = (block_keys(bs - bs.min(axis=0)) << 2) | np.where(nfrac == 1, np.argmax(fs, axis=1), 3)
        key = np.where(nfrac >= 2, -1 - np.arange(len(key)), key)
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        index[seam] = seam[first][inverse.reshape(-1)]
        faces = index[faces]
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    if not ok.all():
        faces = faces[ok]
    used = np.zeros(len(lattice), dtype=bool)
    used[faces] = True
    if used.all():
        return lattice, faces
    remap = np.cumsum(used) - 1
    return lattice[used], remap[faces]
