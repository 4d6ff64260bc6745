"""The house with a gable roof whose eaves overhang its walls: prisms fused by a boolean
union, then remeshed.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ._common import DEFAULT_DETAIL, remesh_to_faces, rest_on_ground


def roof(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A house with a chimney and a gable roof that overhangs its walls, one closed manifold.

    The house is 2 wide (x), 3 deep (z) with walls 1 high; the roof rises 0.75 to its
    ridge (about 37 degrees), is 0.12 thick (vertically), and overhangs 0.35 past the long
    walls (the eaves, where icicles hang) and 0.3 past the gable ends. The pieces are
    fused by a boolean union (manifold3d) and remeshed isotropically (pymeshlab), keeping
    the creases, to about ``60 * detail ** 2`` faces.
    """
    half_w, wall, half_d = 1.0, 1.0, 1.5
    rise, thick, eave, gable = 0.75, 0.12, 0.35, 0.3
    slope = rise / half_w
    ridge = wall + rise  # underside of the roof at the ridge
    out = half_w + eave
    low = wall - eave * slope  # underside of the roof at the eaves
    # The gable walls reach into the middle of the roof slab so no faces of the union coincide.
    house = prism([(-half_w, 0.0), (half_w, 0.0), (half_w, wall + thick / 2),
                   (0.0, ridge + thick / 2), (-half_w, wall + thick / 2)],
                  [[0, 1, 2], [0, 2, 3], [0, 3, 4]], -half_d, half_d)
    slab = prism([(-out, low), (0.0, ridge), (out, low), (out, low + thick),
                  (0.0, ridge + thick), (-out, low + thick)],
                 [[0, 1, 4], [0, 4, 5], [1, 2, 3], [1, 3, 4]], -half_d - gable, half_d + gable)
    chimney = prism([(0.35, 1.2), (0.6, 1.2), (0.6, 2.05), (0.35, 2.05)],
                    [[0, 1, 2], [0, 2, 3]], 0.55, 0.85)
    mesh = trimesh.boolean.union([house, slab, chimney], engine="manifold")
    return rest_on_ground(remesh_to_faces(mesh, 60 * detail ** 2))


def prism(profile, cap_triangles, z0: float, z1: float) -> trimesh.Trimesh:
    """Extrude a counter-clockwise polygon in the xy plane from ``z0`` to ``z1``: a closed solid.

    Parameters
    ----------
    profile : (n, 2) float
        Polygon corners, counter-clockwise seen from +z.
    cap_triangles : (n - 2, 3) int
        A counter-clockwise triangulation of the polygon by its corner indices.
    z0, z1 : float
        ``z0 < z1``.

    Returns
    -------
    trimesh.Trimesh
        ``2 n`` vertices, ``2 n + 2 (n - 2)`` outward-facing faces.
    """
    profile = np.asarray(profile, dtype=np.float64)
    caps = np.asarray(cap_triangles, dtype=np.int64)
    n = len(profile)
    x, y = profile.T
    if 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) <= 0:
        raise ValueError("prism profile must run counter-clockwise")
    if not z0 < z1:
        raise ValueError(f"need z0 < z1, got {z0}, {z1}")
    vertices = np.concatenate([np.c_[profile, np.full(n, z0)], np.c_[profile, np.full(n, z1)]])
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.concatenate([np.stack([i, j, n + j], axis=1), np.stack([i, n + j, n + i], axis=1),
                            caps + n, caps[:, ::-1]])
    return trimesh.Trimesh(vertices, faces, process=False)
