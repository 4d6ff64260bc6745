"""A job's meshes as the exporters write them (`usd`, `gltf`): ``object.ply`` with the normals it
was rendered with, ``ice.ply`` wound outwards with its normals, stage 1's water per vertex; and
`require`, the one-line refusal of a folder that lacks what an export reads.

The object's mesh comes from ``object.ply`` (split along creases, with its normals), the ice
from ``ice.ply`` or the pipeline's mesh in memory, with the normals the scene was written with
(`icefarm.scene.SceneFiles.ice_normals`) when at hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..errors import InputError
from ..jobdir import ICE, OBJECT, WATER
from ..scene import smooth_normals

__all__ = ["Flow", "Surface", "ice_surface", "object_surface", "read_flow", "read_ice", "require", "water_at"]


def require(job_dir: Path, *names: str) -> None:
    """`InputError` in one line naming the first of ``names`` missing from ``job_dir``."""
    for name in names:
        if not (Path(job_dir) / name).is_file():
            raise InputError(f"{job_dir} has no {name}: only a job that rendered can be exported "
                             "(run it first with `icefarm run`, without --no-render)")


@dataclass(frozen=True)
class Surface:
    """A triangle mesh ready for export: ``vertices`` ``(n, 3)`` float32 (m), ``faces``
    ``(m, 3)`` int32 wound outwards, unit vertex ``normals`` ``(n, 3)`` float32."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


def object_surface(job_dir: str | Path) -> Surface:
    """``object.ply``: the object as rendered, split along its creases, with its normals."""
    path = Path(job_dir) / OBJECT
    mesh = trimesh.load(path, process=False)
    vertex = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if vertex is not None and "nx" in vertex.dtype.names:
        normals = np.column_stack([vertex["nx"], vertex["ny"], vertex["nz"]])
    else:
        normals = smooth_normals(mesh.vertices, mesh.faces)
    return Surface(np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32),
                   np.asarray(normals, dtype=np.float32))


def ice_surface(vertices: np.ndarray, faces: np.ndarray, flip: bool, normals: np.ndarray | None = None) -> Surface:
    """The ice wound outwards, with the angle-weighted normals Mitsuba shaded it with
    (`icefarm.scene.smooth_normals`).

    Parameters
    ----------
    vertices : (n, 3) float
        ``ice.ply``'s vertices, meters: kept as they are (same order, float32).
    faces : (m, 3) int
    flip : bool
        The faces wind inwards (`SceneSpec.ice_flip`): each is reversed, so that formats
        without a "flip normals" switch see the outside as the outside.
    normals : (n, 3) float, optional
        Those normals of ``faces`` as given, if at hand (`icefarm.scene.SceneFiles.ice_normals`:
        the scene's writer computed them), sparing a pass over millions of faces. Default:
        computed here.
    """
    faces = np.asarray(faces, dtype=np.int32)
    if normals is not None and np.shape(normals) == np.shape(vertices):
        normals = np.asarray(normals, dtype=np.float32) * np.float32(-1.0 if flip else 1.0)
    else:
        normals = None
    if flip:
        faces = np.ascontiguousarray(faces[:, ::-1])
    if normals is None:
        normals = smooth_normals(vertices, faces).astype(np.float32)
    return Surface(np.asarray(vertices, dtype=np.float32), faces, normals)


def read_ice(job_dir: str | Path, flip: bool) -> Surface:
    """`ice_surface` of ``ice.ply``."""
    mesh = trimesh.load(Path(job_dir) / ICE, process=False)
    return ice_surface(mesh.vertices, mesh.faces, flip)


@dataclass(frozen=True)
class Flow:
    """``water.ply``: stage 1's flow mesh's ``vertices`` ``(n, 3)`` (m), with its ``water``
    ``(n,)`` float and ``supply`` ``(n,)`` bool per vertex."""

    vertices: np.ndarray
    water: np.ndarray
    supply: np.ndarray


def read_flow(job_dir: str | Path) -> Flow | None:
    """The job's `Flow` (``water.ply``), or None without one."""
    from ..artifacts import read_water_ply

    path = Path(job_dir) / WATER
    if not path.is_file():
        return None
    flow = trimesh.load(path, process=False)
    supply, water = read_water_ply(path, len(flow.vertices))
    return Flow(np.asarray(flow.vertices), water, supply)


def water_at(flow: Flow, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stage 1's ``water`` (float) and ``supply`` (bool) at ``points`` ``(n, 3)``.

    ``water.ply`` holds them per vertex of the *flow* mesh: the object itself, or a proxy
    (alpha wrap, remesh) with other vertices. Each point takes the values of the nearest
    flow vertex: exact where the flow mesh is the object (``object.ply`` only splits its
    vertices along creases, in place), the nearest proxy vertex (a few millimetres off,
    `proxy.offset`) otherwise.
    """
    from scipy.spatial import cKDTree

    nearest = cKDTree(flow.vertices).query(np.asarray(points, dtype=np.float64))[1]
    return flow.water[nearest], flow.supply[nearest]
