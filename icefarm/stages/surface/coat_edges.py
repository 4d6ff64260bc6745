"""The sharp convex edges that bound the glaze coat's surface samples' planes (`coat`).

A surface sample's plane runs on past a sharp convex edge of its face, and the coat with
it; `convex_edges` finds, per sampled face, the lines of such edges that bound it (its own
and those of faces in its plane within reach), so that `coat_band` counts a lattice
sample's offset from them too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ...geometry import ragged_arange, stable_order
from .coat_band import Edges

# Convex edges where faces meet at more than this (radians) bound their faces' planes
# (`coat_band.Edges`): a sample's plane otherwise runs on up to ~0.6 `coat.SPACING` voxels past
# such an edge, and the coat with it (fins up to 5 mm out at 4 mm voxels along a fence's
# picket edges, wet with thin rivulets); under this the plane strays under a third of a
# voxel off the surface.
_SHARP = math.radians(15.0)


def convex_edges(mesh: trimesh.Trimesh, face: np.ndarray, reach: float) -> Edges | None:
    """The `Edges` of samples on ``face`` (k,): the convex edges sharper than _SHARP of
    their faces, and of the faces in the same plane (within _SHARP / 3) within ``reach``
    across such faces (a strip of thin faces along an edge has samples near it on faces
    that do not touch it), up to 3 a face, its own first. None if there are none.

    Per face, not per sample: on Table 2's dragon (102,516 samples, 6,288 such edges) a
    k-d tree of points along the edges, queried per sample, is about six times slower."""
    used = np.zeros(len(mesh.faces), dtype=bool)
    used[face] = True
    sharp = _sharp_convex(mesh, used)
    if len(sharp) == 0:
        return None
    lines = _edge_lines(mesh, sharp)
    rec_face, rec_line = _spread_lines(mesh, used, lines, reach)
    order = stable_order(rec_face)  # own lines first, then ring by ring
    rec_face, rec_line = rec_face[order], rec_line[order]
    slot = np.arange(len(rec_face)) - np.searchsorted(rec_face, rec_face)
    keep = slot < 3
    rec_face, rec_line, slot = rec_face[keep], rec_line[keep], slot[keep]
    rows = np.unique(rec_face)
    row_of = np.full(len(mesh.faces), -1)
    row_of[rows] = np.arange(len(rows))
    w, n = np.zeros((len(rows), 3, 3)), np.zeros((len(rows), 3, 3))
    lv, nv = np.full((len(rows), 3), -np.inf), np.full((len(rows), 3), -np.inf)
    r = row_of[rec_face]
    w[r, slot], lv[r, slot] = lines.inward[rec_line], lines.level[rec_line]
    n[r, slot], nv[r, slot] = lines.across[rec_line], lines.across_level[rec_line]
    return Edges(row_of[face], w, lv, n, nv)


def _sharp_convex(mesh: trimesh.Trimesh, used: np.ndarray) -> np.ndarray:
    """Indices into ``mesh.face_adjacency`` of the convex edges sharper than _SHARP that
    touch a ``used`` face (per face, bool)."""
    adj = mesh.face_adjacency
    # (faces without a normal, of no area, bound nothing)
    planar = np.linalg.norm(mesh.face_normals, axis=1) > 0.5
    sharp = np.flatnonzero((mesh.face_adjacency_angles > _SHARP) & used[adj].any(axis=1) & planar[adj].all(axis=1))
    # Convex: the far corner of the second face lies under the first one's plane (trimesh's
    # face_adjacency_convex takes every pair: all 1.4 M of the 3 m house's).
    edge = mesh.face_adjacency_edges[sharp]
    second = mesh.faces[adj[sharp, 1]]
    far = second[(second != edge[:, :1]) & (second != edge[:, 1:])]
    if len(far) != len(sharp):  # a degenerate face: fall back to trimesh's test
        convex = mesh.face_adjacency_convex[sharp]
    else:
        convex = np.einsum("kd,kd->k", mesh.vertices[far] - mesh.vertices[edge[:, 0]],
                           mesh.face_normals[adj[sharp, 0]]) < 0
    return sharp[convex]


@dataclass(frozen=True)
class _Lines:
    """The straight lines of the sharp convex edges, each the edge of one face's plane:
    ``inward``, ``level``, ``normal`` (the face's), ``across`` and ``across_level`` per line
    (as in `Edges`); ``face`` and ``line`` pair each face along an edge with its line."""

    inward: np.ndarray
    level: np.ndarray
    normal: np.ndarray
    across: np.ndarray
    across_level: np.ndarray
    face: np.ndarray
    line: np.ndarray


def _edge_lines(mesh: trimesh.Trimesh, sharp: np.ndarray) -> _Lines:
    """The `_Lines` of the edges ``sharp`` (indices into ``mesh.face_adjacency``)."""
    adj = mesh.face_adjacency
    f = adj[sharp].ravel()  # one line for each face along each edge
    ends = np.repeat(mesh.face_adjacency_edges[sharp], 2, axis=0)
    a = mesh.vertices[ends[:, 0]]
    inward = np.cross(mesh.face_normals[f], mesh.vertices[ends[:, 1]] - a)
    inward *= np.where(np.einsum("kd,kd->k", inward, mesh.triangles[f].mean(axis=1) - a) < 0, -1.0, 1.0)[:, None]
    inward /= np.maximum(np.linalg.norm(inward, axis=1), 1e-300)[:, None]
    level = np.einsum("kd,kd->k", a, inward)
    n_across = mesh.face_normals[adj[sharp][:, ::-1].ravel()]  # the other face's, across the edge
    # The segments of one straight edge (a box's, split by a refinement) are one line: the
    # same plane, the same side, the same line in it, the same plane across.
    n_f = mesh.face_normals[f]
    offset = np.einsum("kd,kd->k", a, n_f)
    same = np.round(np.c_[inward * 1e4, n_f * 1e4, n_across * 1e4,
                          np.c_[level, offset] / mesh.scale * 1e5]).astype(np.int64)
    # rows as single values (as fuse.py welds vertices): unique(axis=0) sorts row by row, 3x slower
    packed = np.ascontiguousarray(same).view(np.dtype((np.void, same.itemsize * same.shape[1]))).reshape(-1)
    _, line_of, inverse = np.unique(packed, return_index=True, return_inverse=True)
    return _Lines(inward[line_of], level[line_of], n_f[line_of], n_across[line_of],
                  np.einsum("kd,kd->k", a[line_of], n_across[line_of]), f, inverse.reshape(-1))


def _spread_lines(mesh: trimesh.Trimesh, used: np.ndarray, lines: _Lines,
                  reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Each line spread ring by ring across the ``used`` faces of its plane while within
    ``reach``: (face, line) pairs, each face's own lines first, then ring by ring."""
    n_faces = len(mesh.faces)
    adj, angle = mesh.face_adjacency, mesh.face_adjacency_angles
    inward, level, normal = lines.inward, lines.level, lines.normal
    n_lines = len(inward)
    both = used[adj].all(axis=1)  # lines spread over the sampled faces only
    flat = adj[(angle < _SHARP / 3) & both]
    flat = np.concatenate([flat, flat[:, ::-1]])
    flat = flat[stable_order(flat[:, 0])]
    start = np.r_[0, np.cumsum(np.bincount(flat[:, 0], minlength=n_faces))]
    flat = flat[:, 1]
    tri = mesh.triangles
    own = np.unique(lines.face * n_lines + lines.line)
    rec_face, rec_line = [own // n_lines], [own % n_lines]
    known = own
    new_face, new_line = rec_face[0], rec_line[0]
    while len(new_face):
        count = start[new_face + 1] - start[new_face]
        nb = flat[ragged_arange(count) + np.repeat(start[new_face], count)]
        line = np.repeat(new_line, count)
        record, first = np.unique(nb * n_lines + line, return_index=True)
        fresh = known[np.minimum(np.searchsorted(known, record), len(known) - 1)] != record
        nb, line, record = nb[first][fresh], line[first][fresh], record[fresh]
        # The face lies wholly on the line's side (in a non-convex plane, an L or a gable's
        # end, the line runs on across the plane), its nearest corner within reach.
        gap = (np.einsum("kvd,kd->kv", tri[nb], inward[line]) - level[line][:, None]).min(axis=1)
        ok = (gap >= -1e-9 * mesh.scale) & (gap <= reach)
        ok &= np.einsum("kd,kd->k", mesh.face_normals[nb], normal[line]) > math.cos(_SHARP / 3)
        new_face, new_line = nb[ok], line[ok]
        # two sorted runs: a stable (run-merging) sort is linear; the default re-sorts all
        # of it on each ring (fandisk has 113)
        known = np.sort(np.concatenate([known, record[ok]]), kind="stable")
        rec_face.append(new_face)
        rec_line.append(new_line)
    return np.concatenate(rec_face), np.concatenate(rec_line)
