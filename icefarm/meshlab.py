"""The one way into and out of pymeshlab: a trimesh mesh as a MeshSet and back.

pymeshlab is imported on first use, so modules that may call it cost nothing to import.
"""

from __future__ import annotations

import numpy as np
import trimesh


def meshset(mesh: trimesh.Trimesh):
    """A ``pymeshlab.MeshSet`` holding ``mesh`` (vertices float64, faces int32, as pymeshlab wants)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(mesh.vertices, dtype=np.float64),
                               np.asarray(mesh.faces, dtype=np.int32)))
    return ms


def current(ms) -> trimesh.Trimesh:
    """The MeshSet's current mesh as a trimesh mesh (float64 / int64, not processed)."""
    mesh = ms.current_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vertex_matrix(), dtype=np.float64),
                           np.asarray(mesh.face_matrix(), dtype=np.int64), process=False)
