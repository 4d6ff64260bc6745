"""Boolean union of two sampled fields, each on its own lattice, run only where they meet."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..geometry import face_any
from .field import Field, values_at
from .fuse_kernel import INNER, OUTER, compacted, kept_outside, vertex_sides, welded
from .march import march_blocks
from .union_region import inner_faces, margin, near_region, restrict, surface_region


def fuse_fields(a: Field | None, b: Field | None, detail: Field | None = None, a_marched=None):
    """Boolean union of the iso-surfaces of two sampled fields, each on its own lattice.

    Both are marched whole. The union only cuts them where they come close, so only there
    does it run (manifold3d): each field is marched again with its samples zeroed outside
    the samples of its cells that may meet the other surface
    (`icefarm.metaballs.union_region`), which closes it with caps out of the other's reach;
    the caps are cut off the union and the rest welds, bit for bit, to the faces of the
    whole meshes outside that region, less those wholly inside the other solid
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
    a_marched : ((n, 3) float, (m, 3) int), optional
        ``a`` marched already (`march_blocks` of its values, blocks and level).

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
            reuse = f is a and a_marched is not None
            lattice, faces = a_marched if reuse else march_blocks(f.values, f.blocks, f.level)
            if len(faces):
                parts.append((f, f.origin + lattice * f.voxel, lattice, faces))
    keeps_a = bool(parts) and parts[0][0] is a
    if len(parts) < 2:
        fused = (parts[0][1], parts[0][3], parts[0][2] if keeps_a else None) if parts else None
    else:
        fused = _local_union(*parts, with_lattice=detail is not None)
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
                fused = _local_union(d_part, (a, verts, lattice, faces), with_lattice=False)
            if fused is None:
                return union_meshes([(verts, faces), (d_part[1], d_part[3])])
    if fused is None:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return fused[0], fused[1]


def _local_union(a, b, with_lattice: bool = True):
    """`fuse_fields` near where the surfaces meet; None when a check fails.

    ``a``, ``b``: (field, vertices in meters, vertices in lattice coordinates, faces).
    The lattice coordinates may be NaN for vertices that the field's marching did not
    make (a mesh that was united before): their faces must lie away from the other surface.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    lattice : (n, 3) float64 or None
        The lattice coordinates of ``a``'s vertices on ``a``'s lattice, NaN for the others;
        None unless ``with_lattice`` (only a later union with a third field reads them).
    """
    # The two sides are independent: both at once (the regions' NumPy work, the compiled
    # marching and face tests leave the GIL).
    with ThreadPoolExecutor(2) as pool:
        sides = list(pool.map(lambda pair: _side(*pair), ((a, b), (b, a))))
    if any(side is None for side in sides):  # too big a region, or a face half inside the other solid
        return None
    u_verts, u_faces, source, origin = _manifold_union([(s.r_verts, s.r_faces) for s in sides])
    keep = np.zeros(len(u_faces), dtype=bool)
    for i, side in enumerate(sides):
        mine = source == i
        keep[mine] = side.r_inner[origin[mine]]
    u_use = vertex_sides(u_faces, keep, len(u_verts))
    u_faces = u_faces[keep]

    # One vertex list: side a, side b, the union; the seams weld on exact positions (where
    # the caps were cut off the union, too).
    va, vb = sides[0].verts, sides[1].verts
    na, nb = len(va), len(vb)
    cand = np.concatenate([sides[0].seam, sides[1].seam + na, np.flatnonzero(u_use == INNER | OUTER) + na + nb])
    verts = np.concatenate([va, vb, u_verts])
    _, first, inverse = np.unique(np.ascontiguousarray(verts[cand]).view(np.dtype((np.void, 24))).reshape(-1),
                                  return_index=True, return_inverse=True)
    index = np.arange(len(verts))
    index[cand] = cand[first][inverse.reshape(-1)]
    parts = tuple(np.ascontiguousarray(f, dtype=np.int64) for f in (sides[0].kept, sides[1].kept, u_faces))
    faces, degenerate = welded(parts, np.array([0, na, na + nb]), index)
    if degenerate:
        return None
    # Away from the seams each part is closed already (the marched meshes and the union).
    touched = np.zeros(len(verts), dtype=bool)
    touched[index[cand]] = True
    if not _closed_around(faces, touched):
        return None
    faces, used = compacted(faces, len(verts))
    if not with_lattice:
        return verts[used], faces, None
    lattice = np.full((len(verts), 3), np.nan)
    lattice[:na] = a[2]
    return verts[used], faces, lattice[used]


@dataclass(frozen=True)
class _Side:
    """One mesh's side of `_local_union`.

    Attributes
    ----------
    verts : (n, 3) float64
        The whole mesh's vertices, meters.
    kept : (k, 3) int64
        Its faces out of the union's region that lie outside the other solid.
    seam : (s,) int64
        Its vertices shared by faces in the region and out of it.
    r_verts, r_faces : arrays
        The mesh marched again on the region alone (closed with caps out of the other's reach).
    r_inner : (f,) bool
        Which of ``r_faces`` lie in the region (the others are caps).
    """

    verts: np.ndarray
    kept: np.ndarray
    seam: np.ndarray
    r_verts: np.ndarray
    r_faces: np.ndarray
    r_inner: np.ndarray


def _side(part, other_part) -> _Side | None:
    """`_local_union`'s work on ``part`` against ``other_part``; None where the region's
    grids would be too big or a face out of the region lies partly inside the other solid."""
    field, verts, lattice, faces = part
    other, other_verts, other_lattice, _ = other_part
    # The other's vertices of no marching of its field lie away from this surface (the
    # contract above): the union runs near those of its marching only.
    marched = np.isfinite(other_lattice).all(axis=1)
    region = surface_region(field, other, other_lattice[marched]) if marched.any() else \
        near_region(field, other_verts, margin(field, other))
    if region is None:
        return None
    inner = inner_faces(lattice, faces, region)
    # The whole mesh's faces in cells that reach out of the region lie off the other
    # surface: each lies wholly inside the other solid (the union covers it: dropped) or
    # wholly outside (kept as it is).
    use = vertex_sides(faces, inner, len(verts))
    covered = np.zeros(len(verts), dtype=np.uint8)
    out = (use & OUTER) != 0
    covered[out] = _inside(other, verts[out])
    kept, split = kept_outside(faces, inner, covered)
    if split:
        return None
    values, blocks = restrict(field, region)
    r_lattice, r_faces = march_blocks(values, blocks, field.level)
    r_inner = inner_faces(r_lattice, r_faces, region)
    return _Side(verts, kept, np.flatnonzero(use == INNER | OUTER), field.origin + r_lattice * field.voxel, r_faces,
                 r_inner)


def _inside(field: Field, points: np.ndarray) -> np.ndarray:
    """Whether the field's nearest sample to each point (n, 3) (meters) is above its level."""
    return values_at(field, np.rint((points - field.origin) / field.voxel).astype(np.int64)) > field.level


def _closed_around(faces: np.ndarray, touched: np.ndarray) -> bool:
    """Whether every edge with an end in ``touched`` (per vertex) joins exactly two faces
    that cross it in opposite directions."""
    f = faces[face_any(touched, faces)]
    e = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)
    e = e[face_any(touched, e)]
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
