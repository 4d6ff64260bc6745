"""Smoothing of the glaze coat's face (`smooth_glaze`).

The coat's field is a patchwork of its surface samples' tangent planes (`coat_band`), two
voxels apart: on a curved object the face it marches carries small kinks at that spacing.
Seen close, the sky they reflect breaks into ragged white flecks on the bunny's glaze (the
close-up view at lookdev; the same flecks at 128 spp without a denoiser, none with the sky
off): a few Taubin steps, which do not shrink the coat, turn them into smooth highlights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import trimesh

from ...geometry import face_any
from ...metaballs import Field, values_at
from ...spatial import nearest, point_index

# Taubin's lambda|mu pair (Taubin 1995), run by trimesh.smoothing.filter_taubin: a
# low-pass filter on the mesh that keeps its volume.
TAUBIN = (0.5, -0.53)
# Vertices where an icicle field holds more than this share of its level are the icicles'
# (their tips, ripples and bases keep their shape) and stay put.
ICICLE_SHARE = 0.25
# No coat vertex moves farther than this, in the coat's voxels (the kinks are up to about
# a millimetre deep at 4 mm voxels: 10 steps move the bunny's coat by 1.1 mm at the median),
# and none moves that lies closer than CLEAR voxels over the object: the coat's face stays
# clear of it (`coat_band.TAPER_END`), and so does its hidden inner face.
MAX_MOVE = 0.3
CLEAR = 0.75


@dataclass(frozen=True)
class CoatVertices:
    """Which ice vertices belong to the glaze coat's face, free to move (`coat_vertices`).

    Attributes
    ----------
    outer : (n,) bool
        The coat's outer face: over the object and on no icicle's face.
    free : (n,) bool
        Those at least `CLEAR` voxels over the object, free to move either way.
    near : (n,) int
        Each outer vertex's nearest vertex of the covered surface (-1 elsewhere).
    height : (n,) float
        Each outer vertex's height over that vertex's plane, meters (0 elsewhere).
    """

    outer: np.ndarray
    free: np.ndarray
    near: np.ndarray
    height: np.ndarray


def coat_vertices(vertices: np.ndarray, faces: np.ndarray, voxel: float, icicles: list[Field],
                  surface: trimesh.Trimesh) -> CoatVertices:
    """The coat's free vertices in an ice mesh (``vertices`` (n, 3) meters, ``faces`` (m, 3)).

    Parameters
    ----------
    voxel : float
        The glaze coat's voxel (``glaze.voxel_size``), meters (`CLEAR`).
    icicles : list of Field
        The icicles' fields (coarse and fine): where one reaches `ICICLE_SHARE` of its level
        the vertex is an icicle's, and so are the others of its faces (they anchor the coat
        where it meets one).
    surface : trimesh.Trimesh
        What the coat covers: a vertex's height over it is read off the plane of its nearest
        vertex (a flow mesh's vertices are at most ``storm.flow_edge`` apart).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(vertices)
    icy = np.zeros(n, dtype=bool)
    for field in icicles:
        lattice = np.rint((vertices - field.origin) / field.voxel).astype(np.int64)
        icy |= values_at(field, lattice) > ICICLE_SHARE * field.level
    free = ~icy
    if len(faces):
        free[faces[face_any(icy, faces)]] = False
    near_all = np.full(n, -1, dtype=np.int64)
    height_all = np.zeros(n)
    outer = free.copy()
    cand = np.flatnonzero(free)
    if len(cand):
        _, near = nearest(point_index(surface.vertices), vertices[cand], np.inf)
        height = np.einsum("kd,kd->k", vertices[cand] - surface.vertices[near], surface.vertex_normals[near])
        free[cand] = height >= CLEAR * voxel
        outer[cand] = height > 0
        near_all[cand], height_all[cand] = near, height
    near_all[~outer], height_all[~outer] = -1, 0.0
    return CoatVertices(outer, free, near_all, height_all)


def smooth_glaze(vertices: np.ndarray, faces: np.ndarray, voxel: float, coat: CoatVertices,
                 iterations: int) -> np.ndarray:
    """The ice mesh with the glaze coat's vertices smoothed.

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices, in meters.
    faces : (m, 3) int
    voxel : float
        The glaze coat's voxel (``glaze.voxel_size``), meters: it bounds the moves
        (`MAX_MOVE`).
    coat : CoatVertices
        Which vertices may move (`coat_vertices`).
    iterations : int
        Taubin steps (each a lambda and a mu step, `TAUBIN`); 0 returns ``vertices``.

    Returns
    -------
    (n, 3) float64
        The moved vertices (a copy), or ``vertices`` itself when nothing moves.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    free = coat.free
    if iterations <= 0 or len(faces) == 0 or not free.any():
        return vertices
    # trimesh's Taubin filter on the free vertices and their neighbours only (a 3 m house:
    # 0.18 M of 1.36 M vertices move; about six times faster than over the whole mesh), with the
    # equal-weight Laplacian of `trimesh.smoothing.laplacian_calculation` in which a pinned
    # vertex is its own only neighbour. (Built here: that one sizes its matrix by the largest
    # vertex in the faces, and a pinned vertex past it aborts the process in scipy.)
    sub = faces[face_any(free, faces)]
    edges = sub[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    edges = edges[free[edges[:, 0]]]
    in_ring = np.zeros(len(vertices), dtype=bool)
    in_ring[edges] = True
    ring = np.flatnonzero(in_ring)
    local = (np.cumsum(in_ring) - 1)[edges]
    pinned = np.flatnonzero(~free[ring])
    adjacency = trimesh.graph.edges_to_coo(np.concatenate([local, np.stack([pinned, pinned], axis=1)]),
                                           count=len(ring)).tocsr().astype(np.float64)
    operator = scipy.sparse.diags(1.0 / np.asarray(adjacency.sum(axis=1)).ravel()) @ adjacency
    lamb, mu = TAUBIN
    part = trimesh.Trimesh(vertices[ring], np.zeros((0, 3), dtype=np.int64), process=False, validate=False)
    start = vertices[ring]
    move = trimesh.smoothing.filter_taubin(part, lamb=lamb, nu=-mu, iterations=2 * iterations,
                                           laplacian_operator=operator).vertices - start
    length = np.sqrt(np.einsum("kd,kd->k", move, move))
    move *= np.minimum(1.0, MAX_MOVE * voxel / np.maximum(length, 1e-300))[:, None]
    out = vertices.copy()
    out[ring] = start + move
    return out
