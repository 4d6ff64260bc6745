"""Boolean union of two sampled fields, each on its own lattice, run only where they meet."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .field import Field, block_keys
from .march import march_blocks

# Most tiles in the dense grid of a region where two lattices are fused.
_MAX_TILES = 2**22


def fuse_fields(a: Field | None, b: Field | None, detail: Field | None = None):
    """Boolean union of the iso-surfaces of two sampled fields, each on its own lattice.

    Both are marched whole. The union only cuts them where they come close, so only there
    does it run (manifold3d): each field is marched again with its samples zeroed outside
    the tiles near the other surface (`_margin`), which closes it with caps out of the
    other's reach; the caps are cut off the union and the rest welds, bit for bit, to the
    faces of the whole meshes outside those tiles, less those wholly inside the other solid
    (nearest-sample test). Should a check fail (a face there half inside, a seam that does
    not close), the whole meshes go through the boolean instead (`union_meshes`).

    Parameters
    ----------
    a, b : Field or None
        From `sample_field`; None is an empty field.
    detail : Field, optional
        A third field, on a finer lattice, whose surface stays away from ``b``'s (the thin
        ends of icicles meshed finer than their thick parts in ``a``): it is united with
        ``a``'s part of the result the same way, after ``a`` and ``b``.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound, watertight.
    """
    if detail is not None and a is None:
        return fuse_fields(detail, b)
    parts = []
    for f in (a, b):
        if f is not None:
            lattice, faces = march_blocks(f.values, f.blocks, f.level)
            if len(faces):
                parts.append((f, f.origin + lattice * f.voxel, lattice, faces))
    keeps_a = bool(parts) and parts[0][0] is a
    if len(parts) < 2:
        fused = (parts[0][1], parts[0][3], parts[0][2] if keeps_a else None) if parts else None
    else:
        fused = _local_union(*parts)
        if fused is None:
            fused = (*union_meshes([(p[1], p[3]) for p in parts]), None)
    if detail is not None:
        d_lattice, d_faces = march_blocks(detail.values, detail.blocks, detail.level)
        if len(d_faces):
            d_part = (detail, detail.origin + d_lattice * detail.voxel, d_lattice, d_faces)
            if fused is None:
                return d_part[1], d_part[3]
            verts, faces, lattice = fused
            fused = None
            if lattice is not None:  # a's faces near the detail are a's marching: unite there only
                fused = _local_union(d_part, (a, verts, lattice, faces))
            if fused is None:
                return union_meshes([(verts, faces), (d_part[1], d_part[3])])
    if fused is None:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return fused[0], fused[1]


def _margin(field: Field, other: Field) -> float:
    """How far the cells of ``field`` left out of the union must lie from ``other``'s
    vertices.

    A point of the other surface lies within one of its voxels of a vertex of it (a
    marching-cubes triangle fits in a cell), and a cell spans one cell diagonal, so a cell
    with a sample this far from the other's vertices stays more than half of the other's
    cell diagonal off the other surface: out of its reach, and on the side of it that the
    nearest sample of the other field says (`_inside`).
    """
    return 1.05 * (math.sqrt(3) * field.voxel + (1 + 0.5 * math.sqrt(3)) * other.voxel)


def _local_union(a, b):
    """`fuse_fields` near where the surfaces meet; None when a check fails.

    ``a``, ``b``: (field, vertices in meters, vertices in lattice coordinates, faces).
    The lattice coordinates may be NaN for vertices that the field's marching did not
    make (a mesh that was united before): their faces must lie away from the other surface.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    lattice : (n, 3) float64
        The lattice coordinates of ``a``'s vertices on ``a``'s lattice, NaN for the others.
    """
    sides = []
    for (field, verts, lattice, faces), (other, other_verts, *_) in ((a, b), (b, a)):
        tiles = _near_tiles(field, other_verts, _margin(field, other))
        if tiles is None:
            return None
        inner = _inner_faces(lattice, faces, *tiles)
        values, blocks = _restrict(field, *tiles)
        r_lattice, r_faces = march_blocks(values, blocks, field.level)
        r_inner = _inner_faces(r_lattice, r_faces, *tiles)
        sides.append((field, verts, faces, inner, field.origin + r_lattice * field.voxel, r_faces, r_inner))
    # The whole mesh's faces in cells that reach out of the region lie off the other
    # surface: each lies wholly inside the other solid (the union covers it: dropped) or
    # wholly outside (kept as it is).
    outside = []
    for (_, verts, faces, inner, *_), other in zip(sides, (sides[1][0], sides[0][0])):
        out = np.flatnonzero(~inner)
        used = _used(faces[out], len(verts))
        covered = np.zeros(len(verts), dtype=bool)
        covered[used] = _inside(other, verts[used])
        count = covered[faces[out]].sum(axis=1)
        if ((count > 0) & (count < 3)).any():
            return None
        outside.append(out[count == 0])
    u_verts, u_faces, source, origin = _manifold_union([(s[4], s[5]) for s in sides])
    keep = np.zeros(len(u_faces), dtype=bool)
    for i, side in enumerate(sides):
        mine = source == i
        keep[mine] = side[6][origin[mine]]
    nu = len(u_verts)
    u_edge = np.flatnonzero(_used(u_faces[keep], nu) & _used(u_faces[~keep], nu))  # where caps were cut off
    u_faces = u_faces[keep]

    # One vertex list: side a, side b, the union; the seams weld on exact positions.
    (_, va, fa, ia, *_), (_, vb, fb, ib, *_) = sides
    na, nb = len(va), len(vb)
    seam = [np.flatnonzero(_used(f[i], len(v)) & _used(f[~i], len(v))) + off
            for v, f, i, off in ((va, fa, ia, 0), (vb, fb, ib, na))]
    cand = np.concatenate(seam + [u_edge + na + nb])
    verts = np.concatenate([va, vb, u_verts])
    _, first, inverse = np.unique(np.ascontiguousarray(verts[cand]).view(np.dtype((np.void, 24))).reshape(-1),
                                  return_index=True, return_inverse=True)
    index = np.arange(len(verts))
    index[cand] = cand[first][inverse.reshape(-1)]
    faces = index[np.concatenate([fa[outside[0]], fb[outside[1]] + na, u_faces + na + nb])]
    if ((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])).any():
        return None
    # Away from the seams each part is closed already (the marched meshes and the union).
    touched = np.zeros(len(verts), dtype=bool)
    touched[index[cand]] = True
    if not _closed_around(faces, touched):
        return None
    used = _used(faces, len(verts))
    lattice = np.full((len(verts), 3), np.nan)
    lattice[:na] = a[2]
    return verts[used], (np.cumsum(used) - 1)[faces], lattice[used]


def _used(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertices that ``faces`` use."""
    used = np.zeros(n, dtype=bool)
    used[faces] = True
    return used


def _near_tiles(field: Field, points: np.ndarray, margin: float):
    """Tiles (cubes of ``tile^3`` samples) of ``field``'s lattice within ``margin`` of any
    of ``points`` (k, 3) (meters), as a dense boolean grid; None if it would be too big.

    Returns
    -------
    region : (tx, ty, tz) bool
        Every tile with a point within ``margin`` is in it (some a little farther are too).
    lo : (3,) int
        Tile coordinates of ``region[0, 0, 0]``.
    tile : int
        Samples per tile edge.
    """
    block = field.values.shape[1]
    # Tiles about half the margin: finer ones make bigger grids, coarser ones wider regions.
    finest = min(margin / (2 * field.voxel), block)
    for tile in (t for t in range(1, block + 1) if block % t == 0 and 2 * t > finest):
        per = block // tile
        k = int(math.ceil(margin / (tile * field.voxel)))
        lo = (field.blocks.min(axis=0) - 1) * per - k  # from the (empty) lower neighbours' tiles
        shape = (field.blocks.max(axis=0) + 2) * per + k - lo
        if int(np.prod(shape)) <= _MAX_TILES:
            break
    else:
        return None
    t = np.floor((points - field.origin) / (field.voxel * tile)).astype(np.int64) - lo
    t = t[((t >= 0) & (t < shape)).all(axis=1)]
    occupied = np.zeros(tuple(shape), dtype=np.uint8)
    occupied[t[:, 0], t[:, 1], t[:, 2]] = 1
    # A tile j tiles away from a point's tile is at least (j - 1) tile edges away from it.
    return ndimage.maximum_filter(occupied, size=2 * k + 1, mode="constant") > 0, lo, tile


def _inner_faces(lattice: np.ndarray, faces: np.ndarray, region, lo, tile) -> np.ndarray:
    """Faces whose marching-cubes cell has all 8 samples in ``region``: marching the
    restricted field gives them bit for bit.

    A face's cell is the floor of its vertices' least coordinates, the same for all faces
    of a cell, so a cell's faces (and the vertex some cells add inside) never split between
    the two sides of the seam. A cell across tiles asks for each tile its samples lie in
    (asking for the whole 2 x 2 x 2 block left faces near a third field's surface out of the
    region).
    """
    # NaN (a vertex of no marching of this field): a cell far outside every region
    corner = np.floor(np.where(np.isfinite(lattice), lattice, -2.0**30)).astype(np.int32)
    shape = np.array(region.shape)
    lo = lo.astype(np.int32)
    # A vertex lies in its face's cell, so in one of the tiles the cell's samples lie in: only
    # the faces whose three vertices lie in the region's tiles can be inner (the bench's
    # whole meshes: a tenth of their faces).
    t = corner // tile - lo
    in_region = (t >= 0).all(axis=1) & (t < shape).all(axis=1)
    in_region[in_region] = region[t[in_region, 0], t[in_region, 1], t[in_region, 2]]
    inner = np.zeros(len(faces), dtype=bool)
    maybe = np.flatnonzero(in_region[faces].all(axis=1))
    f = faces[maybe]
    cell = np.minimum(np.minimum(corner[f[:, 0]], corner[f[:, 1]]), corner[f[:, 2]])
    t = cell // tile - lo
    across = cell % tile == tile - 1  # per axis: the cell's samples reach the next tile
    ok = ((t >= 0) & (t < shape - across)).all(axis=1)
    ok[ok] = region[t[ok, 0], t[ok, 1], t[ok, 2]]
    for step in list(np.ndindex(2, 2, 2))[1:]:  # every other tile the cell's 8 samples lie in
        rows = np.flatnonzero(ok & across[:, np.array(step, dtype=bool)].all(axis=1))
        u = t[rows] + np.array(step, dtype=np.int32)
        ok[rows] = region[u[:, 0], u[:, 1], u[:, 2]]
    inner[maybe] = ok
    return inner


def _restrict(field: Field, region, lo, tile):
    """``field``'s blocks that reach ``region``, with their samples outside it zeroed.

    Returns
    -------
    values : (k, B, B, B) float32
    blocks : (k, 3) int64
    """
    block = field.values.shape[1]
    per = block // tile
    first = field.blocks * per - lo
    o = np.arange(per)
    mask = region[first[:, 0, None, None, None] + o[:, None, None],
                  first[:, 1, None, None, None] + o[None, :, None],
                  first[:, 2, None, None, None] + o[None, None, :]]
    keep = mask.reshape(len(mask), -1).any(axis=1)
    mask = mask[keep]
    for axis in (1, 2, 3):
        mask = np.repeat(mask, tile, axis=axis)
    return field.values[keep] * mask, field.blocks[keep]


def _inside(field: Field, points: np.ndarray) -> np.ndarray:
    """Whether the field's nearest sample to each point (n, 3) (meters) is above its level."""
    block = field.values.shape[1]
    s = np.rint((points - field.origin) / field.voxel).astype(np.int64)
    bc = s // block
    ok = ((bc >= 0) & (bc < 2**20)).all(axis=1)
    keys = block_keys(field.blocks)
    key = block_keys(np.where(ok[:, None], bc, 0))
    i = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
    ok &= keys[i] == key
    r = s - bc * block
    return ok & (field.values[i, r[:, 0], r[:, 1], r[:, 2]] > field.level)


def _closed_around(faces: np.ndarray, touched: np.ndarray) -> bool:
    """Whether every edge with an end in ``touched`` (per vertex) joins exactly two faces
    that cross it in opposite directions."""
    f = faces[touched[faces].any(axis=1)]
    e = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)
    e = e[touched[e].any(axis=1)]
    n = len(touched)
    key = np.sort(e[:, 0] * n + e[:, 1])
    back = np.sort(e[:, 1] * n + e[:, 0])
    return bool((np.diff(key) != 0).all() and np.array_equal(key, back))


def union_meshes(parts):
    """Boolean union of closed meshes (manifold3d), as one watertight mesh.

    Parameters
    ----------
    parts : sequence of ((n, 3) float, (m, 3) int)
        Closed, outward-wound meshes in meters; empty ones are skipped.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Outward-wound, watertight.

    Raises
    ------
    ValueError
        A part that is not a closed, oriented 2-manifold.
    """
    vertices, faces, _, _ = _manifold_union(parts)
    return vertices, faces


def _manifold_union(parts):
    """`union_meshes`, with each face's source: the index of its part and of its face there.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    source, origin : (m,) int64
    """
    import manifold3d

    solids, index, ids = [], [], []
    first_id = manifold3d.Manifold.reserve_ids(len(parts))
    for i, (v, f) in enumerate(parts):
        if len(f) == 0:
            continue
        # One face id per triangle: manifold3d then neither merges nor re-triangulates
        # coplanar neighbours, so untouched triangles come out as they went in.
        solid = manifold3d.Manifold(manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(v, dtype=np.float64),
            tri_verts=np.ascontiguousarray(f, dtype=np.uint64),
            run_index=np.array([0, 3 * len(f)], dtype=np.uint64),
            run_original_id=np.array([first_id + i], dtype=np.uint32),
            face_id=np.arange(len(f), dtype=np.uint64)))
        if solid.status() != manifold3d.Error.NoError:
            raise ValueError(f"mesh {i} of the union is not a closed oriented manifold: {solid.status()}")
        solids.append(solid)
        index.append(i)
        ids.append(first_id + i)
    if not solids:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids = np.array(ids)
    union = solids[0] if len(solids) == 1 else manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if union.status() != manifold3d.Error.NoError:
        raise ValueError(f"the union of {len(solids)} meshes failed: {union.status()}")
    out = union.to_mesh64()
    vertices = np.array(out.vert_properties, dtype=np.float64).reshape(-1, max(out.vert_properties.shape[1], 3))[:, :3]
    faces = np.array(out.tri_verts, dtype=np.int64).reshape(-1, 3)
    runs = np.array(out.run_index, dtype=np.int64) // 3
    run_source = np.array(index)[np.searchsorted(ids, np.array(out.run_original_id, dtype=np.int64))]
    source = np.repeat(run_source, np.diff(runs))
    origin = np.array(out.face_id, dtype=np.int64)
    return vertices, faces, source, origin
