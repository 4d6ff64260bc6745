"""What the mesh generators share: detail levels, the triangles of a vertex grid, remeshing
and setting a mesh on the ground.
"""

from __future__ import annotations

import numpy as np
import trimesh

DEFAULT_DETAIL = 8
MAX_DETAIL = 64


def grid_faces(rows: int, cols: int, wrap: bool = False) -> np.ndarray:
    """Triangles of a ``rows`` x ``cols`` vertex grid stored row-major (vertex ``r * cols + c``).

    Each cell ``(r, c)`` becomes ``[a, b, d]`` and ``[a, d, e]`` with ``a = (r, c)``,
    ``b = (r + 1, c)``, ``d = (r + 1, c + 1)``, ``e = (r, c + 1)``: counter-clockwise
    around ``d/dr x d/dc``. With ``wrap`` the last column joins the first (a tube).

    Returns
    -------
    (2 * (rows - 1) * (cols - 1 + wrap), 3) int
    """
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols if wrap else cols - 1), indexing="ij")
    a = r * cols + c
    e = r * cols + (c + 1) % cols
    b, d = a + cols, e + cols
    quads = np.stack([a, b, d, e], axis=-1).reshape(-1, 4)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def remesh_to_faces(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """Isotropic remeshing to about ``faces`` triangles; creases over 30 degrees are kept."""
    import pymeshlab

    from ..meshlab import current, meshset

    length = np.sqrt(4.0 * mesh.area / (np.sqrt(3.0) * faces))
    ms = meshset(mesh)
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(float(length)), iterations=6)
    return current(ms)


def rest_on_ground(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Shift the mesh so its lowest point is on y = 0; plain float64 / int64 arrays."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64).copy()
    vertices[:, 1] -= vertices[:, 1].min()
    return trimesh.Trimesh(vertices, np.asarray(mesh.faces, dtype=np.int64), process=False)
