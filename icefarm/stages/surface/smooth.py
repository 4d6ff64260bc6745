"""Smoothing of the glaze coat's face (`smooth_glaze`).

The coat's field is a patchwork of its surface samples' tangent planes (`coat_band`), two
voxels apart: on a curved object the face it marches carries small kinks at that spacing.
Seen close, the sky they reflect broke into ragged white flecks on the bunny's glaze (the
close-up view at lookdev; the same flecks at 128 spp without a denoiser, none with the sky
off): a few Taubin steps, which do not shrink the coat, turn them into smooth highlights.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import trimesh

from ...geometry import face_any, nearest, point_index
from ...metaballs import Field, values_at

# Taubin's lambda|mu pair (Taubin 1995; trimesh.smoothing.filter_taubin's defaults): a
# low-pass filter on the mesh that keeps its volume.
TAUBIN = (0.5, -0.53)
# Vertices where an icicle field holds more than this share of its level are the icicles'
# (their tips, ripples and bases keep their shape) and stay put.
ICICLE_SHARE = 0.25
# No coat vertex moves farther than this, in the coat's voxels (the kinks are up to about
# a millimetre deep at 4 mm voxels: 10 steps moved the bunny's coat by 1.1 mm at the median),
# and none moves that lies closer than CLEAR voxels over the object: the coat's face stays
# clear of it (`coat_band.TAPER_END`), and so does its hidden inner face.
MAX_MOVE = 0.3
CLEAR = 0.75


def smooth_glaze(vertices: np.ndarray, faces: np.ndarray, coat: Field, icicles: list[Field],
                 surface: trimesh.Trimesh, iterations: int) -> np.ndarray:
    """The ice mesh with the glaze coat's vertices smoothed.

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices, in meters.
    faces : (m, 3) int
    coat : Field
        The glaze coat's field: its voxel bounds the moves (`MAX_MOVE`).
    icicles : list of Field
        The icicles' fields (coarse and fine): where one reaches `ICICLE_SHARE` of its level
        the vertex is an icicle's and does not move, nor do the vertices around it.
    surface : trimesh.Trimesh
        What the coat covers: a vertex's height over it is read off the plane of its nearest
        vertex (a flow mesh's vertices are at most ``storm.flow_edge`` apart).
    iterations : int
        Taubin steps (each a lambda and a mu step); 0 returns ``vertices``.

    Returns
    -------
    (n, 3) float64
        The moved vertices (a copy), or ``vertices`` itself when nothing moves.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if iterations <= 0 or len(faces) == 0:
        return vertices
    icy = np.zeros(len(vertices), dtype=bool)
    for field in icicles:
        lattice = np.rint((vertices - field.origin) / field.voxel).astype(np.int64)
        icy |= values_at(field, lattice) > ICICLE_SHARE * field.level
    free = ~icy
    # The vertices of a face with an icicle's stay too: they anchor the coat where it meets one.
    free[faces[face_any(icy, faces)]] = False
    cand = np.flatnonzero(free)
    if len(cand) == 0:
        return vertices
    _, near = nearest(point_index(surface.vertices), vertices[cand], np.inf)
    height = np.einsum("kd,kd->k", vertices[cand] - surface.vertices[near], surface.vertex_normals[near])
    free[cand] = height >= CLEAR * coat.voxel
    if not free.any():
        return vertices
    # Only the faces around the free vertices: their rows of the mesh's adjacency are whole.
    neighbours = _neighbours(faces[face_any(free, faces)], len(vertices))
    return _taubin(vertices, neighbours, free, iterations, MAX_MOVE * coat.voxel)


def _neighbours(faces: np.ndarray, n: int) -> scipy.sparse.csr_matrix:
    """(n, n) 0/1 matrix of the mesh's edges (each vertex's neighbours along them)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    m = scipy.sparse.csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    m.data[:] = 1.0  # an edge of two faces was counted twice
    return m


def _taubin(vertices, neighbours, free, iterations, max_move):
    """Taubin steps on the ``free`` vertices, each towards (lambda) then away from (mu) the
    mean of its neighbours; no vertex ends farther than ``max_move`` from where it was."""
    degree = np.asarray(neighbours.sum(axis=1)).ravel()
    rows = np.flatnonzero(free & (degree > 0))
    mean = scipy.sparse.diags(1.0 / degree[rows]) @ neighbours[rows]
    out = vertices.copy()
    for _ in range(iterations):
        for factor in TAUBIN:
            out[rows] += factor * (mean @ out - out[rows])
    move = out[rows] - vertices[rows]
    length = np.sqrt(np.einsum("kd,kd->k", move, move))
    far = length > max_move
    out[rows[far]] = vertices[rows[far]] + move[far] * (max_move / length[far])[:, None]
    return out
