"""Glaze ice as one continuous clear coat: a narrow-band signed-distance field over the wet surface.

The coat is the region ``-inner < D < T`` around the wet part of the flow mesh, where D
is the signed distance to the surface (positive outside) and T the ice thickness of
Equation 3 at the nearest point of the surface. Its outer face lies T above the surface
everywhere, whatever the thickness, the size of the object or the density of its mesh;
its inner face lies ``inner`` (``INNER`` voxels) under the surface, hidden in the
(opaque) object, so that a coat thinner than a voxel still makes a sheet two voxels
thick that marching cubes never tears. Past the edge of the wet faces (the rim) the coat
thins linearly to nothing over ``edge`` (its inner part ends there too); faces that
touch an excluded vertex (the sole an object stands on) get none at all.

D and T come from an even sample of the surface (``SPACING`` voxels apart, with face
normals): a lattice sample takes its nearest surface sample (scipy cKDTree) and
``D = (p - s) . n``, rounded off with the lateral offset past the sample spacing so that
convex creases get round offsets instead of fins; dry samples bound the coat (a lattice
sample nearer to a dry face than to a wet one is not under the wet one, so the inner
face never comes out through a thin wall) and carry the taper, from the distance to the
rim. Only the narrow band is sampled: tiles of the lattice found coarse to fine, each
kept where its centre's distance says the coat may come within a voxel of it; where no
crease or change of wet/dry/excluded comes near, the samples of a tile share their
centre's nearest surface sample (one plane: the same distance, exactly). The result has
the block layout of `icefarm.metaballs.Field` and is stored so that marching cubes,
which interpolates ``value ** _POWER`` linearly (`icefarm.metaballs.march._march_domain`),
interpolates the signed distance itself: the iso-surface lies where the distance says,
to a fraction of a voxel, and fuses with the icicles' field through
`icefarm.metaballs.fuse_fields`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ...errors import InputError
from ...geometry import ray_caster
from ...metaballs.field import BLOCK, CUTOFF, Field, _block_keys
from ...metaballs.march import _POWER

# Depth of the coat's hidden inner face under the surface, in voxels: a coat of any
# thickness makes a sheet at least this thick, which marching cubes cannot tear.
INNER = 2.0
# A coat is never thinner than this, in voxels, however thin the wall under it: a thinner
# sheet would tear into holes (the coat then shows a little on the far side of the wall).
MIN_SHEET = 1.75
# Spacing of the surface samples, in voxels (one per SPACING^2 / 2 voxel faces of surface):
# the nearest sample of a point of the surface lies within ~0.6 SPACING of it, which
# D ignores, so this costs no accuracy on flat faces; denser samples cost time.
SPACING = 2.0
# Signed distance (in voxels) over which the stored field goes from the level to twice
# it (after ``** _POWER``): marching cubes sees a linear ramp through the surface.
_RAMP = 2.0
# Edge of a tile (lattice samples) of the narrow band: tiles far from the coat are skipped.
_TILE = 2
# Tiles are found coarse to fine: from tiles of _TILE * 2^_LEVELS samples down to _TILE.
_LEVELS = 2
# Faces that meet at more than this (radians) make a crease: near one, each lattice sample
# finds its own nearest surface sample; elsewhere those of a tile share one (one plane).
_CREASE = math.radians(1.0)
# The lattice's origin sits this many blocks off a multiple of a block (irrational voxels).
_SHIFT = 1.0 + (math.sqrt(5.0) - 2.0) / BLOCK
# Refuse coats whose field would need more memory than this, or more lattice samples
# evaluated than this (about 100 bytes each on the way).
_MAX_FIELD_BYTES = 2 * 2**30
_MAX_POINTS = 60_000_000


def coat_field(flow_mesh: trimesh.Trimesh, thickness: np.ndarray, wet: np.ndarray, voxel: float,
               edge: float, exclude: np.ndarray | None = None, name: str = "glaze.voxel_size",
               cast=None) -> Field | None:
    """The field of a continuous coat of ice ``thickness`` thick over the wet faces.

    Parameters
    ----------
    flow_mesh : trimesh.Trimesh
        In meters, outward normals.
    thickness : (n,) float
        Ice thickness at each vertex of ``flow_mesh`` (Equation 3), in meters; only wet
        vertices' values are read.
    wet : (n,) bool
        Wet vertices; a face with at least two wet vertices (and no excluded one) is wet
        and is coated whole.
    voxel : float
        Lattice spacing, in meters.
    edge : float
        Past the edge of the wet faces the coat thins linearly to nothing over this
        distance, in meters (0: it ends in a step).
    exclude : (n,) bool, optional
        Vertices where no ice may be: faces that touch one get none.
    name : str
        The parameter that set ``voxel``, named in errors.
    cast : callable, optional
        An `icefarm.geometry.ray_caster` of ``flow_mesh``, if one is at hand.

    Returns
    -------
    Field or None
        Level 1, inside where the value is above it; None where nothing is wet.

    Raises
    ------
    InputError
        A voxel so fine that the field would need more than ``_MAX_FIELD_BYTES`` or
        ``_MAX_POINTS`` lattice samples.
    """
    faces = np.asarray(flow_mesh.faces, dtype=np.int64)
    nv = len(flow_mesh.vertices)
    wet = np.asarray(wet, dtype=bool).reshape(-1)
    thickness = np.maximum(np.nan_to_num(np.asarray(thickness, dtype=np.float64).reshape(-1)), 0.0)
    if len(wet) != nv or len(thickness) != nv:
        raise ValueError(f"wet and thickness need one value per flow-mesh vertex ({nv})")
    blocked = np.zeros(len(faces), dtype=bool)
    if exclude is not None:
        exclude = np.asarray(exclude, dtype=bool).reshape(-1)
        if len(exclude) != nv:
            raise ValueError(f"exclude needs one value per flow-mesh vertex ({nv})")
        wet = wet & ~exclude
        blocked = exclude[faces].any(axis=1)
    is_wet = (wet[faces].sum(axis=1) >= 2) & ~blocked
    wet_faces = np.flatnonzero(is_wet)
    if len(wet_faces) == 0 or flow_mesh.area_faces[wet_faces].sum() <= 0:
        return None
    voxel = float(voxel)
    edge = max(float(edge), 0.0)
    h = SPACING * voxel
    inner = INNER * voxel
    # Refuse before sampling: the band holds at least this many lattice samples.
    band = flow_mesh.area_faces[wet_faces].sum() / voxel**2 * (INNER + 2.0 + thickness[wet].max() / voxel)
    if band > _MAX_POINTS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze (about {band:.3g} lattice samples "
            f"near the coat, at most {_MAX_POINTS}); raise {name}")

    # Samples on the wet faces, with the thickness interpolated from their wet vertices.
    pts, face, bary = surface_samples(flow_mesh, wet_faces, h)
    if len(pts) == 0:
        return None
    w = bary * wet[faces[face]]
    t_wet = (thickness[faces[face]] * w).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    # How far from a wet sample a lattice sample can be inside the coat, with voxels to
    # spare (marching needs the samples next to the surface).
    reach = float(t_wet.max()) + inner + edge + 2.0 * voxel
    # Samples on the faces around, within reach of the band: the surface that bounds
    # the coat (a lattice sample nearer to a dry face is not under the wet one).
    around = _faces_near(flow_mesh, wet_faces, pts, 2.0 * reach + 2.0 * h)
    dpts, dface, _ = surface_samples(flow_mesh, around, h)
    if len(dpts):  # those in or next to a cell of that size with wet samples
        cell = 2.0 * reach + 2.0 * h
        lo = pts.min(axis=0) - 2 * cell
        wet_cells = np.unique(_block_keys(np.floor((pts - lo) / cell).astype(np.int64) + 1))
        step = np.array([(a << 42) | (b << 21) | c for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)])
        near = np.unique((wet_cells[:, None] + step[None, :]).ravel())
        cells = np.floor((dpts - lo) / cell).astype(np.int64) + 1
        ok = (cells >= 0).all(axis=1)
        keep = np.flatnonzero(ok)[np.isin(_block_keys(cells[ok]), near)]
        dpts, dface = dpts[keep], dface[keep]
    rim = _rim(flow_mesh, is_wet, blocked, wet, thickness, 0.5 * voxel) if edge > 0 else None
    kind = np.where(is_wet, 1, np.where(blocked, -1, 0)).astype(np.int8)
    features = _features(flow_mesh, np.r_[wet_faces, around], kind, voxel)
    all_pts, all_face = np.concatenate([pts, dpts]), np.r_[face, dface]
    normals = flow_mesh.face_normals[all_face]
    all_t = np.r_[t_wet, np.zeros(len(dpts))]
    depth = _inner_depth(flow_mesh, all_pts, normals, all_t, kind, inner, voxel, cast)
    sole = flow_mesh.vertices[exclude] if exclude is not None else np.zeros((0, 3))
    return _sample_band(all_pts, normals, all_t, kind[all_face], depth, rim, features, sole, edge, voxel, reach,
                        h, name)


def _inner_depth(mesh, pts, normals, thick, kind, inner, voxel, cast):
    """How deep under each sample the coat reaches: ``inner``, but under a wall thinner
    than twice that whose far side is not wet (ray cast along the inward normal), 45 % of
    the wall, so the coat stays inside; unless the sheet would then be thinner than
    ``MIN_SHEET`` voxels (it would tear): then just that thick, through the wall."""
    if cast is None:
        cast = ray_caster(mesh)
    start = 0.05 * voxel
    dist, hit = cast(pts - start * normals, -normals)
    depth = np.full(len(pts), inner)
    thin = np.flatnonzero(np.isfinite(dist) & (dist + start < 2.0 * inner))
    thin = thin[kind[hit[thin]] != 1]
    depth[thin] = np.maximum(np.minimum(inner, 0.45 * (dist[thin] + start)), MIN_SHEET * voxel - thick[thin])
    return depth


def _features(mesh: trimesh.Trimesh, faces: np.ndarray, kind: np.ndarray, spacing: float):
    """A tree of points ``spacing`` apart along the edges of ``faces`` where the surface
    creases (faces at more than _CREASE), changes kind (wet, dry, excluded) or ends."""
    used = np.zeros(len(mesh.faces), dtype=bool)
    used[faces] = True
    adj = mesh.face_adjacency
    sel = used[adj].any(axis=1) & ((mesh.face_adjacency_angles > _CREASE) | (kind[adj[:, 0]] != kind[adj[:, 1]]))
    edges = [mesh.face_adjacency_edges[sel]]
    uses = np.bincount(mesh.faces_unique_edges.ravel(), minlength=len(mesh.edges_unique))
    open_edges = np.flatnonzero(uses == 1)
    if len(open_edges):
        edges.append(mesh.edges_unique[open_edges])
    edges = np.concatenate(edges)
    if len(edges) == 0:
        return None
    a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
    count = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing), 1).astype(np.int64)
    which = np.repeat(np.arange(len(edges)), count + 1)
    u = (np.arange(len(which)) - np.repeat(np.cumsum(count + 1) - (count + 1), count + 1)) / count[which]
    return cKDTree(a[which] + u[:, None] * (b - a)[which])


@dataclass(frozen=True)
class _Rim:
    """The edges between the wet faces and the others (not excluded ones): where the
    taper starts. Segment ``j`` runs from ``a[j]`` to ``b[j]`` with the coat ``ta[j]`` to
    ``tb[j]`` thick; ``normal`` is its wet face's. ``tree`` holds points along the
    segments (``seg``: theirs)."""

    tree: cKDTree
    seg: np.ndarray
    a: np.ndarray
    b: np.ndarray
    ta: np.ndarray
    tb: np.ndarray
    normal: np.ndarray

    def query(self, foot: np.ndarray, bound: float) -> np.ndarray:
        """The segment nearest to each point (-1: none within ``bound``)."""
        d, j = self.tree.query(foot, k=1, distance_upper_bound=bound, workers=-1)
        return np.where(np.isfinite(d), self.seg[np.minimum(j, len(self.seg) - 1)], -1)

    def near(self, foot: np.ndarray, j: np.ndarray):
        """Distance from ``foot`` (k, 3) to segment ``j`` (k,) and the coat's thickness at
        its nearest point there."""
        a, e = self.a[j], self.b[j] - self.a[j]
        u = np.clip(np.einsum("kd,kd->k", foot - a, e) / np.maximum(np.einsum("kd,kd->k", e, e), 1e-300), 0, 1)
        off = foot - a - u[:, None] * e
        return np.sqrt(np.einsum("kd,kd->k", off, off)), self.ta[j] + u * (self.tb[j] - self.ta[j])


def _rim(mesh: trimesh.Trimesh, is_wet, blocked, wet, thickness, spacing) -> _Rim | None:
    """The `_Rim` of the wet faces, its tree's points ``spacing`` apart."""
    fe = mesh.faces_unique_edges
    n_edges = len(mesh.edges_unique)
    wet_uses = np.bincount(fe[is_wet].ravel(), minlength=n_edges)
    blocked_uses = np.bincount(fe[blocked].ravel(), minlength=n_edges)
    f_of = np.repeat(np.flatnonzero(is_wet), 3)
    e_of = fe[is_wet].ravel()
    sel = (wet_uses[e_of] == 1) & (blocked_uses[e_of] == 0)
    f_of, e_of = f_of[sel], e_of[sel]
    if len(e_of) == 0:
        return None
    ends = mesh.edges_unique[e_of]
    a, b = mesh.vertices[ends[:, 0]], mesh.vertices[ends[:, 1]]
    # An end that is dry takes the thickness of the wet one (as inside the wet face).
    ta, tb = thickness[ends[:, 0]], thickness[ends[:, 1]]
    ta, tb = np.where(wet[ends[:, 0]], ta, tb), np.where(wet[ends[:, 1]], tb, ta)
    count = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(e_of)), count + 1)
    u = (np.arange(len(seg)) - np.repeat(np.cumsum(count + 1) - (count + 1), count + 1)) / count[seg]
    return _Rim(cKDTree(a[seg] + u[:, None] * (b - a)[seg]), seg, a, b, ta, tb, mesh.face_normals[f_of])


def surface_samples(mesh: trimesh.Trimesh, faces: np.ndarray, spacing: float):
    """Evenly spread points on ``faces``: each face cut into ``m^2`` similar triangles, one
    point at each's centroid; ``m`` makes about one point per ``spacing^2 / 2`` of area and
    sub-triangles no longer than ``2 spacing``. Faces without area get none.

    Deterministic: no gaps and no clumps, so the nearest sample of any point of a fat
    face lies within about 0.6 ``spacing`` of it.

    Returns
    -------
    points : (k, 3) float64
    face : (k,) int64
    bary : (k, 3) float64
    """
    faces = np.asarray(faces, dtype=np.int64)
    faces = faces[np.linalg.norm(mesh.face_normals[faces], axis=1) > 0.5]  # a plane, a normal
    if len(faces) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    tri = mesh.triangles[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    area = mesh.area_faces[faces]
    m = np.maximum(np.maximum(np.ceil(np.sqrt(2.0 * area) / spacing), np.ceil(0.5 * longest / spacing)), 1)
    m = m.astype(np.int64)
    out_p, out_f, out_b = [], [], []
    for mm in np.unique(m):
        sel = np.flatnonzero(m == mm)
        pattern = _centroid_pattern(int(mm))  # (mm^2, 3)
        b = np.broadcast_to(pattern, (len(sel),) + pattern.shape).reshape(-1, 3)
        f = np.repeat(sel, len(pattern))
        out_p.append(np.einsum("kj,kjd->kd", b, tri[f]))
        out_f.append(faces[f])
        out_b.append(b)
    return np.concatenate(out_p), np.concatenate(out_f), np.concatenate(out_b)


_PATTERNS: dict[int, np.ndarray] = {}


def _centroid_pattern(m: int) -> np.ndarray:
    """Barycentric centroids of the ``m^2`` triangles of a triangle cut ``m`` ways."""
    if m not in _PATTERNS:
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        i, j = i.ravel(), j.ravel()
        up = i + j <= m - 1
        down = i + j <= m - 2
        u = np.r_[(i[up] + 1 / 3) / m, (i[down] + 2 / 3) / m]
        v = np.r_[(j[up] + 1 / 3) / m, (j[down] + 2 / 3) / m]
        _PATTERNS[m] = np.stack([1 - u - v, u, v], axis=1)
    return _PATTERNS[m]


def _faces_near(mesh: trimesh.Trimesh, wet_faces: np.ndarray, wet_points: np.ndarray, distance: float) -> np.ndarray:
    """Faces other than ``wet_faces`` that come within about ``distance`` of ``wet_points``."""
    tri = mesh.triangles
    centroid = tri.mean(axis=1)
    radius = np.linalg.norm(tri - centroid[:, None, :], axis=2).max(axis=1)
    other = np.ones(len(tri), dtype=bool)
    other[wet_faces] = False
    cand = np.flatnonzero(other)
    if len(cand) == 0:
        return cand
    # Coarse points of the wet region (one per distance-sized cell) bound the search.
    cell = max(distance, 1e-9)
    key = _block_keys(np.floor((wet_points - wet_points.min(axis=0)) / cell).astype(np.int64))
    _, first = np.unique(key, return_index=True)
    coarse = cKDTree(wet_points[first])
    d, _ = coarse.query(centroid[cand], k=1, distance_upper_bound=np.inf, workers=-1)
    return cand[d <= distance + radius[cand] + math.sqrt(3) * cell]


def _sample_band(pts, normals, thick, kind, depth, rim, features, sole, edge, voxel, reach, h,
                 name) -> Field | None:
    """The coat's field on the lattice tiles near the wet samples.

    ``kind`` per sample: 1 wet, 0 dry, -1 excluded. Each lattice sample takes its nearest
    surface sample ``s`` (normal ``n``): ``sd = (p - s) . n``, its lateral offset beyond
    the sample spacing ``l``, the signed distance ``D = sign(sd) sqrt(sd^2 + l^2)`` and
    ``phi = min(T - D, D + depth)`` (positive inside); T is the thickness of a wet ``s``
    and, past the rim, that of the nearest rim point times ``1 - d / edge`` (d: distance
    from the foot ``p - sd n`` to the rim). No coat where ``s`` is excluded, lies past the
    taper or farther than ``reach``. Between wet and excluded samples (and the excluded
    vertices ``sole``) the coat ends in a wall at their bisector, ``phi = (dB - dW) / 2``.
    """
    wet = kind == 1
    blocked = np.concatenate([pts[kind == -1], sole])
    wall = (np.flatnonzero(wet), cKDTree(pts[wet]), cKDTree(blocked)) if len(blocked) else None
    inner, inner_lo = float(depth.max()), float(depth.min())
    pad = BLOCK * voxel + reach  # the lattice's first block stays empty (see _halo_blocks)
    # Off the round coordinates by a fraction of a voxel: faces of boxes and prisms then
    # never lie on lattice planes (samples exactly on the iso-surface).
    origin = (np.floor((pts.min(axis=0) - pad) / (BLOCK * voxel)) - _SHIFT) * (BLOCK * voxel)
    # Coarse tiles within reach of a wet sample, each with bounds on the coat's thickness
    # within reach of it (dry and excluded samples count as 0) ...
    size = _TILE * 2 ** _LEVELS
    k = int(math.ceil(reach / (size * voxel)))
    keys = _block_keys(np.floor((pts - origin) / (size * voxel)).astype(np.int64))
    keys, t_lo, t_hi, has_wet = _reduce(keys, np.where(wet, thick, 0.0), np.where(wet, thick, 0.0), wet)
    for shift in (42, 21, 0):  # separable dilation by k tiles, one axis at a time
        step = np.arange(-k, k + 1) << shift
        keys, t_lo, t_hi, has_wet = _reduce((keys[:, None] + step[None, :]).ravel(), *(
            np.repeat(a, len(step)) for a in (t_lo, t_hi, has_wet)))
    keys, t_lo, t_hi = keys[has_wet], t_lo[has_wet], t_hi[has_wet]
    if len(keys) * size**3 > 8 * _MAX_POINTS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze ({len(keys) * size**3} lattice "
            f"samples within reach of the coat); raise {name}")
    tiles = np.stack([keys >> 42, (keys >> 21) & (2**21 - 1), keys & (2**21 - 1)], axis=1)
    # ... then, level by level down to _TILE, tiles are dropped where their centre says
    # none of their samples is within a voxel of the coat, kept whole where it says all
    # are more than a voxel inside it, and split in eight otherwise.
    tree = cKDTree(pts)
    children = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    solid = []
    while True:
        half = 0.5 * math.sqrt(3) * (size - 1) * voxel
        centre = origin + (tiles * size + 0.5 * (size - 1)) * voxel
        dist, idx = tree.query(centre, k=1, distance_upper_bound=reach + half, workers=-1)
        d_c = np.full(len(centre), np.inf)
        found = np.isfinite(dist)
        d_c[found] = _signed(centre[found] - pts[idx[found]], normals[idx[found]], dist[found], 0.6 * h)[0]
        near = half + voxel
        inside = (d_c > near - inner_lo) & (d_c < t_lo - near)
        keep = (d_c > -(inner + near)) & (d_c < t_hi + near) & ~inside
        if inside.any():
            n_sub = size // _TILE
            sub = np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
            solid.append((tiles[inside][:, None, :] * n_sub + sub[None]).reshape(-1, 3))
        tiles, t_lo, t_hi = tiles[keep], t_lo[keep], t_hi[keep]
        if size == _TILE:
            nearest = np.where(found, idx, -1)[keep]
            # A tile's samples share its centre's nearest surface sample where no crease or
            # change of kind comes near enough to give any of them another (their nearest
            # lies within dist + 2 half of the centre).
            shared = found[keep].copy()
            if features is not None and shared.any():
                bound = dist[keep][shared] + 2.0 * half + h
                d_f, _ = features.query(centre[keep][shared], k=1, distance_upper_bound=bound.max(), workers=-1)
                shared[shared] = d_f > bound
            # Shared dry tiles share the rim segment nearest to their centre too.
            rim_seg = None
            dry = shared & (kind[np.maximum(nearest, 0)] == 0)
            if rim is not None and dry.any():
                rim_seg = np.full(len(tiles), -1)
                c, j = centre[keep][dry], nearest[dry]
                foot = c - np.einsum("kd,kd->k", c - pts[j], normals[j])[:, None] * normals[j]
                rim_seg[dry] = rim.query(foot, edge + 2.0 * half)
            break
        size //= 2
        tiles = (2 * tiles[:, None, :] + children[None]).reshape(-1, 3)
        t_lo, t_hi = np.repeat(t_lo, 8), np.repeat(t_hi, 8)
    npoints = len(tiles) * _TILE**3
    if npoints > _MAX_POINTS or npoints * 4 > _MAX_FIELD_BYTES:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze ({npoints} lattice samples "
            f"near the coat, at most {_MAX_POINTS}); raise {name}")
    o = np.arange(_TILE)
    local = np.stack(np.meshgrid(o, o, o, indexing="ij"), axis=-1).reshape(-1, 3)
    values = np.empty(npoints, dtype=np.float32)
    chunk = max(1, 1_000_000 // _TILE**3)
    for i in range(0, len(tiles), chunk):
        p = origin + (tiles[i:i + chunk, None, :] * _TILE + local[None]).reshape(-1, 3) * voxel
        # Where the surface is flat around a tile, its samples share the centre's nearest
        # surface sample (the same plane: the same distance); elsewhere each finds its own.
        flat = np.repeat(shared[i:i + chunk], _TILE**3)
        phi = np.empty(len(p))
        phi[flat] = _phi(tree, p[flat], normals, thick, kind, rim, edge, depth, reach, 0.6 * h + half,
                         np.repeat(nearest[i:i + chunk], _TILE**3)[flat],
                         None if rim_seg is None else np.repeat(rim_seg[i:i + chunk], _TILE**3)[flat])
        phi[~flat] = _phi(tree, p[~flat], normals, thick, kind, rim, edge, depth, reach, 0.6 * h, wall=wall)
        values[i * _TILE**3:i * _TILE**3 + len(p)] = _encode(phi, voxel)
    if solid:  # more than a voxel inside: any value above the level marches the same
        solid = np.concatenate(solid)
        tiles = np.concatenate([tiles, solid])
        values = np.r_[values, np.full(len(solid) * _TILE**3, _encode(np.array([voxel]), voxel)[0])]
    if len(tiles) == 0:
        return None
    # Tiles into blocks (_block_keys order); absent tiles of a block stay 0 (outside).
    per = BLOCK // _TILE
    bc = tiles // per
    keys = _block_keys(bc)
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


def _signed(v, n, dist, tol):
    """Signed distance from offsets ``v`` (k, 3) to samples of normal ``n``: the height
    over the sample's plane, rounded off with the lateral offset past ``tol``."""
    sd = np.einsum("kd,kd->k", v, n)
    extra = np.maximum(np.sqrt(np.maximum(dist**2 - sd**2, 0.0)) - tol, 0.0)
    return np.sign(sd) * np.sqrt(sd**2 + extra**2), sd


def _phi(tree, points, normals, thick, kind, rim, edge, depth, reach, tol, nearest=None, seg=None, wall=None):
    """``phi`` (meters, positive inside the coat) at ``points`` (see `_sample_band`), from
    their nearest samples (``nearest``, -1 for none; queried when not given).

    The points of a dry sample lie past the rim: the coat there tapers with the distance
    to the nearest rim segment, found per point or given (``seg``, -1: none near; the
    samples of a tile sharing one, `_sample_band`). With ``wall`` (wet sample indices,
    a tree of the wet samples, one of the excluded ones), the coat stops at the bisector
    between wet and excluded samples.
    """
    if nearest is None:
        dist, nearest = tree.query(points, k=1, distance_upper_bound=reach, workers=-1)
        nearest = np.where(np.isfinite(dist), nearest, -1)
    phi = np.full(len(points), -reach)
    found = np.flatnonzero(nearest >= 0)
    i = nearest[found]
    v = points[found] - tree.data[i]
    k = kind[i]
    d, sd = _signed(v, normals[i], np.sqrt(np.einsum("kd,kd->k", v, v)), tol)
    t = np.where(k == 1, thick[i], -np.inf)
    dry = np.flatnonzero(k == 0)
    if rim is not None and len(dry):
        foot = points[found[dry]] - sd[dry, None] * normals[i[dry]]
        j = rim.query(foot, edge) if seg is None else seg[found[dry]]
        dry, foot, j = dry[j >= 0], foot[j >= 0], j[j >= 0]
        d_rim, t_rim = rim.near(foot, j)
        facing = np.einsum("kd,kd->k", normals[i[dry]], rim.normal[j]) > -0.5
        t[dry] = np.where(facing & (d_rim < edge), t_rim * (1.0 - d_rim / edge), -np.inf)
    p = np.minimum(t - d, d + depth[i])
    if wall is not None:
        wet_index, wet_tree, blocked_tree = wall
        sel = np.flatnonzero(k != 0)  # nearest to a wet or an excluded sample
        q = points[found[sel]]
        d_b, _ = blocked_tree.query(q, k=1, distance_upper_bound=reach, workers=-1)
        d_w = np.sqrt(np.einsum("kd,kd->k", v[sel], v[sel]))
        cut = np.flatnonzero(k[sel] == -1)
        if len(cut):  # nearest to an excluded sample: the coat of the nearest wet one, walled
            d_b[cut] = np.minimum(d_b[cut], d_w[cut])
            d_cut, j = wet_tree.query(q[cut], k=1, distance_upper_bound=reach, workers=-1)
            ok = np.isfinite(d_cut)
            d_w[cut] = d_cut
            cut, j, d_cut = cut[ok], wet_index[j[ok]], d_cut[ok]
            dj = _signed(q[cut] - tree.data[j], normals[j], d_cut, tol)[0]
            p[sel[cut]] = np.minimum(thick[j] - dj, dj + depth[j])
        p[sel] = np.minimum(p[sel], 0.5 * (d_b - d_w))
    phi[found] = np.where(np.isfinite(p) & (d < reach), p, -reach)
    return phi


def _encode(phi: np.ndarray, voxel: float) -> np.ndarray:
    """Field values whose ``** _POWER`` is linear in ``phi`` around the level 1."""
    ramp = _RAMP * voxel
    low = CUTOFF**_POWER  # march clamps the field at CUTOFF * level (level 1)
    g = np.clip(1.0 + phi / ramp, low, 2.0)
    return (g ** (1.0 / _POWER)).astype(np.float32)
