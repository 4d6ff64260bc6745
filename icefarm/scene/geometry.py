"""Mesh data for renderers: winding, crease-aware normals, a fast binary PLY writer."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..compiled import compiled
from ..geometry import face_cross, signed_volume, unit


def winds_inward(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether a closed, consistently wound mesh has its faces wound inwards.

    Looks only at the faces around the vertex furthest along X, whose summed normal must
    point along +X when the winding is outward: a few faces instead of every face of a
    million-face mesh. Falls back to the sign of the `signed_volume` when that sum is
    degenerate.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    extreme = int(np.argmax(vertices[:, 0]))
    ring = faces[np.flatnonzero(faces.reshape(-1) == extreme) // 3]
    normal_x = face_cross(vertices, ring)[:, 0].sum() if len(ring) else 0.0
    scale = np.ptp(vertices, axis=0).max() ** 2
    if abs(normal_x) > 1e-12 * scale:
        return bool(normal_x < 0)
    return signed_volume(vertices, faces) < 0


def _sum_rows(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Rows of ``values`` ``(k, 3)`` summed into ``n`` bins by ``index`` ``(k,)``."""
    return np.column_stack([np.bincount(index, weights=values[:, i], minlength=n) for i in range(3)])


def smooth_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted unit vertex normals ``(n, 3)``; zero for unused vertices.

    Each face adds its unit normal weighted by its angle at the vertex (Thuermer and
    Wuethrich 1998): the normals Mitsuba computes for a mesh loaded without them, so a
    POV-Ray scene shades like the Mitsuba one. Those of trimesh's ``mesh.vertex_normals``
    (`trimesh.geometry.weighted_vertex_normals`), in one compiled pass over the faces
    (`_angle_weighted_sums`): the lookdev car's 2.3 M faces in 0.23 s, against 0.65 s for
    the same sums in NumPy (angles by ``arctan2``, ``bincount`` per corner); trimesh's took
    1.70 s for 1.3 M faces.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    """
    coords = np.ascontiguousarray(vertices, dtype=np.float64)
    summed = np.zeros((len(coords), 3))
    _angle_weighted_sums(coords, np.ascontiguousarray(faces, dtype=np.int64), summed)
    return unit(summed)


@compiled()
def _angle_weighted_sums(vertices, faces, out):
    """Add to ``out`` (n, 3) each face's normal times twice its area over its angle at each
    corner: its unit normal weighted by that angle."""
    for f in range(len(faces)):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
        bx, by, bz = vertices[b, 0], vertices[b, 1], vertices[b, 2]
        cx, cy, cz = vertices[c, 0], vertices[c, 1], vertices[c, 2]
        # edge k leaves corner k
        e0x, e0y, e0z = bx - ax, by - ay, bz - az
        e1x, e1y, e1z = cx - bx, cy - by, cz - bz
        e2x, e2y, e2z = ax - cx, ay - cy, az - cz
        nx = e2y * e0z - e2z * e0y
        ny = e2z * e0x - e2x * e0z
        nz = e2x * e0y - e2y * e0x
        twice = math.sqrt(nx * nx + ny * ny + nz * nz)
        if twice == 0.0:
            continue
        # |edge k x edge k-1| is twice the area at every corner: the angle needs no arccos
        w0 = math.atan2(twice, -(e0x * e2x + e0y * e2y + e0z * e2z)) / twice
        w1 = math.atan2(twice, -(e1x * e0x + e1y * e0y + e1z * e0z)) / twice
        w2 = math.atan2(twice, -(e2x * e1x + e2y * e1y + e2z * e1z)) / twice
        for v, w in ((a, w0), (b, w1), (c, w2)):
            out[v, 0] += nx * w
            out[v, 1] += ny * w
            out[v, 2] += nz * w


def crease_split(mesh: trimesh.Trimesh, angle: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split vertices along edges sharper than ``angle`` degrees, for smooth shading with creases.

    Each face corner joins the corners of the same vertex in faces that meet it across a
    smooth edge; every group becomes one vertex with the area-weighted normal of its faces.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    angle : float
        Dihedral angle (degrees) above which an edge stays sharp.

    Returns
    -------
    vertices : (k, 3) float
    normals : (k, 3) float, unit
    faces : (m, 3) int, same faces and order as ``mesh.faces``
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    n_corners = faces.size
    corner_of = lambda f, v: 3 * f + np.argmax(faces[f] == v[:, None], axis=1)  # noqa: E731
    pairs = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    if len(pairs):
        smooth = np.asarray(mesh.face_adjacency_angles) < np.radians(angle)
        pairs, edges = pairs[smooth], np.asarray(mesh.face_adjacency_edges)[smooth]
        a = np.concatenate([corner_of(pairs[:, 0], edges[:, 0]), corner_of(pairs[:, 0], edges[:, 1])])
        b = np.concatenate([corner_of(pairs[:, 1], edges[:, 0]), corner_of(pairs[:, 1], edges[:, 1])])
    else:
        a = b = np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_corners, n_corners))
    _, group = connected_components(graph, directed=False)
    # Groups never span two vertices (only corners of one vertex are joined); renumber them.
    used, new_index = np.unique(group, return_inverse=True)
    corner_vertex = faces.ravel()
    out_vertices = np.empty((len(used), 3))
    out_vertices[new_index] = vertices[corner_vertex]
    normals = unit(_sum_rows(new_index, np.repeat(face_cross(vertices, faces), 3, axis=0), len(used)))
    return out_vertices, normals, new_index.reshape(-1, 3)


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None) -> None:
    """Binary little-endian PLY: float32 positions (and normals), int32 triangle indices."""
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    vert = np.empty(len(vertices), dtype=fields)
    vert["x"], vert["y"], vert["z"] = vertices.T
    if normals is not None:
        vert["nx"], vert["ny"], vert["nz"] = np.asarray(normals).T
    face = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, faces
    header = ["ply", "format binary_little_endian 1.0", "comment icefarm", f"element vertex {len(vert)}"]
    header += [f"property float {name}" for name, _ in fields]
    header += [f"element face {len(face)}", "property list uchar int vertex_indices", "end_header\n"]
    with open(path, "wb") as f:
        f.write("\n".join(header).encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())
