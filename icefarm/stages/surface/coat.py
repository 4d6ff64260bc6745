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
normals): a lattice sample takes its nearest surface sample (a k-d tree) and
``D = (p - s) . n``, rounded off with the lateral offset past the sample spacing so that
convex creases get round offsets instead of fins (near a sharp convex edge, the offset past
it, and at least the height over the plane across it: the sample's plane ends there), and T
carried from the sample to the foot by the thickness's slope along the face; dry samples
bound the coat (a lattice
sample nearer to a dry face than to a wet one is not under the wet one, so the inner
face never comes out through a thin wall) and carry the taper, from the distance to the
rim. The lattice is sampled in the narrow band around the coat, and stored as a field
that marching cubes reads as the signed distance itself (`coat_band`); it fuses with
the icicles' field through `icefarm.metaballs.fuse_fields`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ...errors import InputError
from ...geometry import cross, ragged_arange, squared_lengths
from ...metaballs.field import Field, block_keys
from ...spatial import nearest, point_index, ray_caster
from .coat_band import MAX_BAND_POINTS, BandLattice, BandSamples, Thickness, sample_band
from .coat_edges import convex_edges
from .coat_kernel import PointTree, point_tree

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
# Faces that meet at more than this (radians) make a crease: near one, each lattice sample
# finds its own nearest surface sample; elsewhere those of a tile share one (one plane).
_CREASE = math.radians(1.0)


@dataclass(frozen=True)
class CoatOptions:
    """The lattice a coat is sampled on and how it ends (`coat_field`).

    Attributes
    ----------
    voxel : float
        Lattice spacing, in meters.
    edge : float
        Past the edge of the wet faces the coat thins linearly to nothing over this
        distance, in meters (0: it ends in a step).
    name : str
        The parameter that set ``voxel``, named in errors.
    """

    voxel: float
    edge: float = 0.0
    name: str = "glaze.voxel_size"


def coat_field(flow_mesh: trimesh.Trimesh, thickness: np.ndarray, wet: np.ndarray, options: CoatOptions,
               exclude: np.ndarray | None = None, cast=None) -> Field | None:
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
    options : CoatOptions
        The lattice spacing, the taper past the wet faces, the parameter named in errors.
    exclude : (n,) bool, optional
        Vertices where no ice may be: faces that touch one get none.
    cast : callable, optional
        An `icefarm.spatial.ray_caster` of ``flow_mesh``, if one is at hand.

    Returns
    -------
    Field or None
        Level 1, inside where the value is above it; None where nothing is wet.

    Raises
    ------
    InputError
        A voxel so fine that the field would need more than ``_MAX_FIELD_BYTES`` or
        ``MAX_BAND_POINTS`` lattice samples.
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
    voxel, name = float(options.voxel), options.name
    edge = max(float(options.edge), 0.0)
    h = SPACING * voxel
    inner = INNER * voxel
    # Refuse before sampling: the band holds at least this many lattice samples.
    band = flow_mesh.area_faces[wet_faces].sum() / voxel**2 * (INNER + 2.0 + thickness[wet].max() / voxel)
    if band > MAX_BAND_POINTS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much glaze (about {band:.3g} lattice samples "
            f"near the coat, at most {MAX_BAND_POINTS}); raise {name}")

    # Samples on the wet faces, with the thickness interpolated from their wet vertices.
    pts, face, bary = surface_samples(flow_mesh, wet_faces, h)
    if len(pts) == 0:
        return None
    w = bary * wet[faces[face]]
    t_wet = (thickness[faces[face]] * w).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    slope = _thickness_slope(flow_mesh, thickness, wet, wet_faces)[face]
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
        wet_cells = np.unique(block_keys(np.floor((pts - lo) / cell).astype(np.int64) + 1))
        step = np.array([(a << 42) | (b << 21) | c for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)])
        near = np.unique((wet_cells[:, None] + step[None, :]).ravel())
        cells = np.floor((dpts - lo) / cell).astype(np.int64) + 1
        ok = (cells >= 0).all(axis=1)
        keep = np.flatnonzero(ok)[np.isin(block_keys(cells[ok]), near)]
        dpts, dface = dpts[keep], dface[keep]
    rim = _rim(flow_mesh, is_wet, blocked, wet, thickness, 0.5 * voxel) if edge > 0 else None
    kind = np.where(is_wet, 1, np.where(blocked, -1, 0)).astype(np.int8)
    features = _features(flow_mesh, np.r_[wet_faces, around], kind, voxel)
    all_pts, all_face = np.concatenate([pts, dpts]), np.r_[face, dface]
    normals = flow_mesh.face_normals[all_face]
    all_t = np.r_[t_wet, np.zeros(len(dpts))]
    depth = _inner_depth(flow_mesh, all_pts, normals, all_t, kind, inner, voxel, cast)
    sole = flow_mesh.vertices[exclude] if exclude is not None else np.zeros((0, 3))
    dry = np.zeros(len(dpts))
    low, high = _thickness_range(flow_mesh, thickness, wet, wet_faces)
    thick = Thickness(all_t, np.concatenate([slope, np.zeros((len(dpts), 3))]),
                      np.r_[np.fmin(low[face], t_wet), dry], np.r_[np.fmax(high[face], t_wet), dry])
    samples = BandSamples(all_pts, normals, kind[all_face], thick, depth,
                          edges=convex_edges(flow_mesh, all_face, 0.6 * h + voxel))
    return sample_band(samples, BandLattice(voxel, reach, h, edge=edge, name=name), rim, features, sole)


def _thickness_range(mesh: trimesh.Trimesh, thickness: np.ndarray, wet: np.ndarray,
                     faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least and the greatest thickness of the wet vertices of each of ``faces`` (each
    with a wet vertex) and of their edge neighbours, per mesh face ((f,) each, NaN off
    ``faces``): a sample's thickness carried along its slope stays within these, exact where
    the thickness is linear (a lattice sample's nearest surface sample may lie on the next
    face), bounded where it is not (the slope of a small face of noisy thickness carried
    past it makes lumps of +-5 mm on a car's windscreen)."""
    t = np.where(wet, thickness, np.nan)
    low, high = t.copy(), t.copy()
    a, b = np.asarray(mesh.edges_unique).T
    for u, v in ((a, b), (b, a)):
        np.fmin.at(low, u, t[v])
        np.fmax.at(high, u, t[v])
    lo, hi = np.full(len(mesh.faces), np.nan), np.full(len(mesh.faces), np.nan)
    corners = mesh.faces[faces]
    lo[faces], hi[faces] = np.nanmin(low[corners], axis=1), np.nanmax(high[corners], axis=1)
    return lo, hi


def _thickness_slope(mesh: trimesh.Trimesh, thickness: np.ndarray, wet: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Per face, the gradient of the thickness interpolated linearly over it from its
    vertices (m/m, (f, 3), in the face's plane), on the faces ``at`` (k,) (0 elsewhere); 0 on
    faces not wet at all three vertices.

    A lattice sample reads the thickness at its foot from its nearest surface sample's value
    and this slope: the sample's value alone makes the coat's outer face a staircase of
    plateaus, one per sample (0.08 mm steps where the thickness changes by 1 cm per metre),
    which the sun picks out as a hammered-glass glitter on the car's windscreen.
    """
    faces = np.asarray(mesh.faces)[at]
    vertices = np.asarray(mesh.vertices)
    v0 = vertices[faces[:, 0]]
    e1, e2 = vertices[faces[:, 1]] - v0, vertices[faces[:, 2]] - v0
    n = cross(e1, e2)
    nn = np.einsum("fd,fd->f", n, n)
    full = np.flatnonzero(wet[faces].all(axis=1) & (nn > 0))
    e1, e2, n, t = e1[full], e2[full], n[full], thickness[faces[full]]
    grad = np.zeros((len(mesh.faces), 3))
    grad[at[full]] = ((t[:, 1] - t[:, 0])[:, None] * cross(e2, n) + (t[:, 2] - t[:, 0])[:, None] * cross(n, e1)) \
        / nn[full, None]
    return grad


def _inner_depth(mesh, pts, normals, thick, kind, inner, voxel, cast):
    """How deep under each sample the coat reaches: ``inner``, but under a wall thinner
    than twice that whose far side is not wet (ray cast along the inward normal), 45 % of
    the wall, so the coat stays inside; unless the sheet would then be thinner than
    ``MIN_SHEET`` voxels (it would tear): then just that thick, through the wall."""
    if cast is None:
        cast = ray_caster(mesh)
    start = 0.05 * voxel
    # Only a wall thinner than twice ``inner`` matters: the rays need look no farther (a
    # hundredth more, for single precision).
    dist, hit = cast(pts - start * normals, -normals, far=1.01 * max(2.0 * inner - start, 0.0))
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
    u = ragged_arange(count + 1) / count[which]
    return point_tree(a[which] + u[:, None] * (b - a)[which])


@dataclass(frozen=True)
class _Rim:
    """The edges between the wet faces and the others (not excluded ones): where the
    taper starts. Segment ``j`` runs from ``a[j]`` to ``b[j]`` with the coat ``ta[j]`` to
    ``tb[j]`` thick; ``normal`` is its wet face's. ``tree`` holds points along the
    segments (``seg``: theirs)."""

    tree: PointTree
    seg: np.ndarray
    a: np.ndarray
    b: np.ndarray
    ta: np.ndarray
    tb: np.ndarray
    normal: np.ndarray

    def query(self, foot: np.ndarray, bound: float) -> np.ndarray:
        """The segment nearest to each point (-1: none within ``bound``)."""
        _, j = self.tree.nearest(foot, bound)
        return np.where(j >= 0, self.seg[j], -1)


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
    u = ragged_arange(count + 1) / count[seg]
    return _Rim(point_tree(a[seg] + u[:, None] * (b - a)[seg]), seg, a, b, ta, tb, mesh.face_normals[f_of])


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
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    longest = np.sqrt(np.maximum(np.maximum(squared_lengths(a - c), squared_lengths(b - a)), squared_lengths(c - b)))
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
    other = np.ones(len(mesh.faces), dtype=bool)
    other[wet_faces] = False
    cand = np.flatnonzero(other)
    if len(cand) == 0:
        return cand
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)[cand]]
    centroid = tri.mean(axis=1)
    radius = np.sqrt(squared_lengths(tri - centroid[:, None, :]).max(axis=1))
    # Coarse points of the wet region (one per distance-sized cell) bound the search.
    cell = max(distance, 1e-9)
    key = block_keys(np.floor((wet_points - wet_points.min(axis=0)) / cell).astype(np.int64))
    _, first = np.unique(key, return_index=True)
    d, _ = nearest(point_index(wet_points[first]), centroid)
    return cand[d <= distance + radius + math.sqrt(3) * cell]
