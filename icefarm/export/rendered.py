"""What a finished job rendered, read from its folder for the exporters (`usd`, `gltf`).

``scene.json`` (`icefarm.scene.spec.SceneSpec`) is the record of the render, from which
``scene.xml`` and ``scene.pov`` were written: the cameras Mitsuba looked through, the sun,
the sky and how it is turned, the ground, the ice's look (ior, roughness, tint, the medium
inside) and the object's material. Reading it, rather than framing the cameras again from
the render config, gives exactly what was rendered. A job folder without ``scene.json`` is read
from its ``scene.xml`` by `icefarm.scene.legacy` (the material from ``done.json``'s
``object_material``, gravity from ``params.yaml``). The object's mesh comes from
``object.ply`` (split along creases, with the normals it was rendered with), the ice from
``ice.ply``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..errors import InputError
from ..jobdir import ICE, OBJECT, PARAMS, SCENE_SPEC, SCENE_XML, WATER, read_job, read_views
from ..scene import geometry as geo
from ..scene.camera import Camera
from ..scene.legacy import spec_from_xml
from ..scene.material import Material, material_from_dict
from ..scene.spec import TINT_DISTANCE_M, Ground, IceShading, read_spec

__all__ = ["METAL_F0", "TINT_DISTANCE_M", "Ground", "IceShading", "Pbr", "Rendered", "Surface", "ice_surface",
           "object_surface", "pbr", "read_ice", "read_rendered", "require", "water_at"]

# Normal-incidence reflectance (linear RGB) of Mitsuba's conductors, as a PBR metal's base
# colour: the usual table of F0 values (Hoffman, "Physically Based Shading", SIGGRAPH course).
METAL_F0 = {
    "Al": (0.913, 0.922, 0.924),
    "Ag": (0.972, 0.960, 0.915),
    "Au": (1.000, 0.766, 0.336),
    "Cu": (0.955, 0.638, 0.538),
    "Cr": (0.549, 0.556, 0.554),
}


@dataclass(frozen=True)
class Pbr:
    """A manifest material as metallic-roughness PBR (UsdPreviewSurface, glTF).

    ``roughness`` is perceptual (the square root of Mitsuba's GGX alpha); ``specular`` False
    for a purely diffuse material, which has no highlight at all in Mitsuba.
    """

    base_color: tuple[float, float, float]
    metallic: float
    roughness: float
    specular: bool


def pbr(material: Material) -> Pbr:
    """`Pbr` of a validated object material (`scene.material.material_from_dict`)."""
    if material.type == "metal":
        return Pbr(METAL_F0[material.metal], 1.0, float(np.sqrt(material.roughness)), True)
    if material.type == "plastic":
        return Pbr(tuple(material.color), 0.0, float(np.sqrt(material.roughness)), True)
    return Pbr(tuple(material.color), 0.0, 1.0, False)


@dataclass(frozen=True)
class Rendered:
    """A job's render, as `read_rendered` finds it.

    Attributes
    ----------
    cameras : tuple of Camera
        One per view, the main view first (meters, the job's frame).
    view_names : tuple of str
        Each view's name (``views.json``), e.g. ``three_quarter``, ``ice``.
    width, height : int
        Image size, pixels.
    sky : Path
        The equirectangular sky image, in the job folder.
    sky_scale : float
        Its radiance scale.
    sky_frame : (3, 3) float
        Rows right, up, front: where the sky image's local X, Y, Z point.
    sun : (3,) float or None
        Unit vector towards the sun; None without a sun.
    sun_irradiance : (3,) float
        Linear RGB irradiance of the sun, W/m^2 (Mitsuba's scale).
    ice : IceShading or None
        None when the job has no ice.
    gravity : (3,) float
        Unit gravity direction (``params.yaml``).
    material : Material
        The object's validated material.
    ground : Ground or None
        The ground plane the render stood the object on; None without one.
    """

    cameras: tuple[Camera, ...]
    view_names: tuple[str, ...]
    width: int
    height: int
    sky: Path
    sky_scale: float
    sky_frame: np.ndarray
    sun: np.ndarray | None
    sun_irradiance: np.ndarray
    ice: IceShading | None
    gravity: np.ndarray
    material: Material
    ground: Ground | None = None


def require(job_dir: Path, *names: str) -> None:
    """`InputError` in one line naming the first of ``names`` missing from ``job_dir``."""
    for name in names:
        if not (Path(job_dir) / name).is_file():
            raise InputError(f"{job_dir} has no {name}: only a job that rendered can be exported "
                             "(run it first with `icefarm run`, without --no-render)")


def read_rendered(job_dir: str | Path, material: Material | Mapping | None = None) -> Rendered:
    """What the job in ``job_dir`` rendered (see `Rendered`): its ``scene.json``
    (`icefarm.scene.spec`), or for a job from before it, its ``scene.xml``.

    Parameters
    ----------
    job_dir : path
        A job folder with ``scene.xml`` and ``params.yaml``; ``views.json`` names the views.
    material : Material or mapping, optional
        The object's material; default ``done.json``'s ``object_material``.

    Raises
    ------
    InputError
        A file missing, or a ``scene.xml`` that is not icefarm's.
    """
    job_dir = Path(job_dir)
    require(job_dir, SCENE_XML, PARAMS)
    if (job_dir / SCENE_SPEC).is_file():
        try:
            spec = read_spec(job_dir / SCENE_SPEC)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{job_dir / SCENE_SPEC}: not a {SCENE_SPEC} written by icefarm ({exc})") from None
    else:  # a job from before scene.json: what scene.xml says
        job = read_job(job_dir)
        own = material if material is not None else job.stats.get("object_material")
        views = read_views(job_dir)
        names = [v["name"] for v in views] if views and all("name" in v for v in views) else None
        gravity = (job.params or {}).get("water.gravity", (0.0, -1.0, 0.0))
        try:
            spec = spec_from_xml(job_dir / SCENE_XML, gravity=gravity, material=material_from_dict(own),
                                 view_names=names)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    return Rendered(
        cameras=spec.cameras, view_names=tuple(v.name for v in spec.views), width=spec.resolution[0],
        height=spec.resolution[1], sky=job_dir / spec.sky.file, sky_scale=spec.sky.scale, sky_frame=spec.frame,
        sun=None if spec.sun is None else spec.sun.direction,
        sun_irradiance=np.zeros(3) if spec.sun is None else spec.sun.irradiance, ice=spec.ice,
        gravity=spec.gravity, material=spec.material if material is None else material_from_dict(material),
        ground=spec.ground)


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
        normals = geo.smooth_normals(mesh.vertices, mesh.faces)
    return Surface(np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32),
                   np.asarray(normals, dtype=np.float32))


def ice_surface(vertices: np.ndarray, faces: np.ndarray, flip: bool, normals: np.ndarray | None = None) -> Surface:
    """The ice wound outwards, with the angle-weighted normals Mitsuba shaded it with.

    Parameters
    ----------
    vertices : (n, 3) float
        ``ice.ply``'s vertices, meters: kept as they are (same order, float32).
    faces : (m, 3) int
    flip : bool
        The faces wind inwards (`IceShading.flip`): each is reversed, so that formats
        without a "flip normals" switch see the outside as the outside.
    normals : (n, 3) float, optional
        Those normals of ``faces`` as given, if at hand (`RenderResult.ice_normals`: the
        render computed them), sparing a pass over millions of faces. Default: computed here.
    """
    faces = np.asarray(faces, dtype=np.int32)
    if normals is not None and np.shape(normals) == np.shape(vertices):
        normals = np.asarray(normals, dtype=np.float32) * np.float32(-1.0 if flip else 1.0)
    else:
        normals = None
    if flip:
        faces = np.ascontiguousarray(faces[:, ::-1])
    if normals is None:
        normals = geo.smooth_normals(vertices, faces).astype(np.float32)
    return Surface(np.asarray(vertices, dtype=np.float32), faces, normals)


def read_ice(job_dir: str | Path, flip: bool) -> Surface:
    """`ice_surface` of ``ice.ply``."""
    mesh = trimesh.load(Path(job_dir) / ICE, process=False)
    return ice_surface(mesh.vertices, mesh.faces, flip)


def water_at(job_dir: str | Path, points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Stage 1's ``water`` (float) and ``supply`` (bool) at ``points`` ``(n, 3)``, or None
    without ``water.ply``.

    ``water.ply`` holds them per vertex of the *flow* mesh: the object itself, or a proxy
    (alpha wrap, remesh) with other vertices. Each point takes the values of the nearest
    flow vertex: exact where the flow mesh is the object (``object.ply`` only splits its
    vertices along creases, in place), the nearest proxy vertex (a few millimetres off,
    `proxy.offset`) otherwise.
    """
    from scipy.spatial import cKDTree

    from ..artifacts import read_water_ply

    path = Path(job_dir) / WATER
    if not path.is_file():
        return None
    flow = trimesh.load(path, process=False)
    supply, water = read_water_ply(path, len(flow.vertices))
    nearest = cKDTree(np.asarray(flow.vertices)).query(np.asarray(points, dtype=np.float64))[1]
    return water[nearest], supply[nearest]

