"""What a finished job rendered, read from its folder for the exporters (`usd`, `gltf`).

``scene.json`` (`icefarm.scene.spec`) is the record of the render, written with
``scene.xml`` from the same values: the cameras Mitsuba looked through, the sun, the sky and
how it is turned, the ground, the ice's look (ior, roughness, tint, the medium inside) and
the object's material. Reading it, rather than framing the cameras again from the render
config, gives exactly what was rendered. Jobs from before ``scene.json`` are read from
their ``scene.xml`` (and the material from ``done.json``'s ``object_material``). The
object's mesh comes from ``object.ply`` (split along creases, with the normals it was
rendered with), the ice from ``ice.ply``.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import yaml

from .errors import InputError
from .jobdir import read_job
from .scene import geometry as geo
from .scene.camera import Camera
from .scene.material import Material, material_from_dict
from .scene.mitsuba import WATER_ICE_IOR
from .scene.spec import SPEC_FILE, read_spec

# Normal-incidence reflectance (linear RGB) of Mitsuba's conductors, as a PBR metal's base
# colour: the usual table of F0 values (Hoffman, "Physically Based Shading", SIGGRAPH course).
METAL_F0 = {
    "Al": (0.913, 0.922, 0.924),
    "Ag": (0.972, 0.960, 0.915),
    "Au": (1.000, 0.766, 0.336),
    "Cu": (0.955, 0.638, 0.538),
    "Cr": (0.549, 0.556, 0.554),
}
# The ice's colour, where a format has no absorbing medium (UsdPreviewSurface): what white
# light looks like after this much ice. 10 cm: the root of a long icicle, where ice shows colour.
TINT_DISTANCE_M = 0.1


@dataclass(frozen=True)
class IceShading:
    """The ice's look as rendered.

    Attributes
    ----------
    ior : float
        Index of refraction (1.31, water ice).
    alpha : float
        GGX roughness alpha of the surface (0: smooth).
    tint : (3,) float
        Transmittance per surface crossing, linear RGB.
    absorption : (3,) float
        Absorption inside the ice, per meter (R, G, B).
    scattering : float
        Scattering inside the ice, per meter.
    flip : bool
        ``ice.ply``'s faces wind inwards (Mitsuba flipped its normals).
    """

    ior: float
    alpha: float
    tint: tuple[float, float, float]
    absorption: tuple[float, float, float]
    scattering: float
    flip: bool

    @property
    def roughness(self) -> float:
        """Perceptual roughness of UsdPreviewSurface and glTF, whose square is the GGX alpha."""
        return float(np.sqrt(self.alpha))

    def color_at(self, distance: float = TINT_DISTANCE_M) -> np.ndarray:
        """``(3,)`` linear RGB of white light after ``distance`` meters of ice (Beer-Lambert)."""
        return np.asarray(self.tint) * np.exp(-np.asarray(self.absorption) * distance)


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
    ground: "Ground | None" = None


@dataclass(frozen=True)
class Ground:
    """The rendered ground plane: a square ``corners`` ``(4, 3)`` (meters, counter-clockwise
    seen from above) of a matte ``color`` ``(3,)``, linear RGB (a checker's mean)."""

    corners: np.ndarray
    color: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.corners[1] - self.corners[0], self.corners[2] - self.corners[0])
        return n / np.linalg.norm(n)


def _ground(shape) -> Ground | None:
    """`Ground` from scene.xml's ``rectangle`` shape (Mitsuba's square -1..1 in its local XY)."""
    if shape is None:
        return None
    m = _floats(shape.find("transform/matrix").get("value")).reshape(4, 4)
    local = np.array([[-1.0, -1.0, 0.0, 1.0], [1.0, -1.0, 0.0, 1.0], [1.0, 1.0, 0.0, 1.0], [-1.0, 1.0, 0.0, 1.0]])
    colors = [_floats(c.get("value").replace(",", " ")) for c in shape.iter("rgb")]
    return Ground(corners=(local @ m.T)[:, :3], color=np.mean(colors, axis=0) if colors else np.full(3, 0.1))


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
    require(job_dir, "scene.xml", "params.yaml")
    if (job_dir / SPEC_FILE).is_file():
        return _from_spec(job_dir, material)
    # a job from before scene.json: what scene.xml says
    try:
        root = ET.parse(job_dir / "scene.xml").getroot()
        defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
        width, height = int(defaults["resx"]), int(defaults["resy"])
        cameras = tuple(_camera(s, width / height) for s in root.iter("sensor"))
        emitters = {e.get("type"): e for e in root.iter("emitter")}
        envmap, sun = emitters["envmap"], emitters.get("directional")
        shapes = {s.get("id"): s for s in root.iter("shape")}
        sky_frame = _floats(envmap.find("transform/matrix").get("value")).reshape(4, 4)[:3, :3].T
    except (ET.ParseError, KeyError, AttributeError, TypeError, ValueError) as exc:
        raise InputError(f"{job_dir / 'scene.xml'}: not a scene.xml written by icefarm ({exc})") from None
    gravity = np.asarray((yaml.safe_load((job_dir / "params.yaml").read_text()).get("water") or {})
                         .get("gravity", (0.0, -1.0, 0.0)), dtype=np.float64)
    if material is None:
        material = read_job(job_dir).stats.get("object_material")
    return Rendered(
        cameras=cameras, view_names=_view_names(job_dir, len(cameras)), width=width, height=height,
        sky=job_dir / _named(envmap, "string", "filename"),
        sky_scale=float(_named(envmap, "float", "scale") or 1.0), sky_frame=sky_frame,
        sun=None if sun is None else -_floats(_named(sun, "vector", "direction")),
        sun_irradiance=np.zeros(3) if sun is None else _floats(_named(sun, "rgb", "irradiance")),
        ice=_ice(shapes["ice"]) if "ice" in shapes else None,
        gravity=gravity / np.linalg.norm(gravity), material=material_from_dict(material),
        ground=_ground(shapes.get("ground")))


def _from_spec(job_dir: Path, material: Material | Mapping | None) -> Rendered:
    """`Rendered` from ``scene.json``."""
    try:
        spec = read_spec(job_dir / SPEC_FILE)
        width, height = (int(v) for v in spec["resolution"])
        cameras = tuple(Camera(origin=np.asarray(c["origin"]), target=np.asarray(c["target"]), up=np.asarray(c["up"]),
                               fov_x=float(c["fov_x"]), fov_y=float(c["fov_y"]), near=float(c["near"]),
                               far=float(c["far"])) for c in spec["cameras"])
        sky, sun, ground, ice = spec["sky"], spec.get("sun"), spec.get("ground"), spec.get("ice")
        rendered = Rendered(
            cameras=cameras, view_names=tuple(v["name"] for v in spec["views"]), width=width, height=height,
            sky=job_dir / sky["file"], sky_scale=float(sky["scale"]), sky_frame=np.asarray(sky["frame"]),
            sun=None if sun is None else np.asarray(sun["direction"]),
            sun_irradiance=np.zeros(3) if sun is None else np.asarray(sun["irradiance"]),
            ice=None if ice is None else IceShading(
                ior=float(ice["ior"]), alpha=float(ice["alpha"]), tint=tuple(float(t) for t in ice["tint"]),
                absorption=tuple(float(a) for a in ice["absorption"]), scattering=float(ice["scattering"]),
                flip=bool(ice["flip"])),
            gravity=np.asarray(spec["gravity"]),
            material=material_from_dict(material if material is not None else spec["object"]["material"]),
            ground=None if ground is None else Ground(np.asarray(ground["corners"]), np.asarray(ground["color"])))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{job_dir / SPEC_FILE}: not a scene.json written by icefarm ({exc})") from None
    return rendered


@dataclass(frozen=True)
class Surface:
    """A triangle mesh ready for export: ``vertices`` ``(n, 3)`` float32 (m), ``faces``
    ``(m, 3)`` int32 wound outwards, unit vertex ``normals`` ``(n, 3)`` float32."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


def object_surface(job_dir: str | Path) -> Surface:
    """``object.ply``: the object as rendered, split along its creases, with its normals."""
    path = Path(job_dir) / "object.ply"
    mesh = trimesh.load(path, process=False)
    vertex = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if vertex is not None and "nx" in vertex.dtype.names:
        normals = np.column_stack([vertex["nx"], vertex["ny"], vertex["nz"]])
    else:
        normals = geo.smooth_normals(mesh.vertices, mesh.faces)
    return Surface(np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32),
                   np.asarray(normals, dtype=np.float32))


def ice_surface(vertices: np.ndarray, faces: np.ndarray, flip: bool) -> Surface:
    """The ice wound outwards, with the angle-weighted normals Mitsuba shaded it with.

    Parameters
    ----------
    vertices : (n, 3) float
        ``ice.ply``'s vertices, meters: kept as they are (same order, float32).
    faces : (m, 3) int
    flip : bool
        The faces wind inwards (`IceShading.flip`): each is reversed, so that formats
        without a "flip normals" switch see the outside as the outside.
    """
    faces = np.asarray(faces, dtype=np.int32)
    if flip:
        faces = np.ascontiguousarray(faces[:, ::-1])
    normals = geo.smooth_normals(vertices, faces)
    return Surface(np.asarray(vertices, dtype=np.float32), faces, normals.astype(np.float32))


def read_ice(job_dir: str | Path, flip: bool) -> Surface:
    """`ice_surface` of ``ice.ply``."""
    mesh = trimesh.load(Path(job_dir) / "ice.ply", process=False)
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

    from .artifacts import read_water_ply

    path = Path(job_dir) / "water.ply"
    if not path.is_file():
        return None
    flow = trimesh.load(path, process=False)
    supply, water = read_water_ply(path, len(flow.vertices))
    nearest = cKDTree(np.asarray(flow.vertices)).query(np.asarray(points, dtype=np.float64))[1]
    return water[nearest], supply[nearest]


def _floats(text: str) -> np.ndarray:
    return np.array(text.replace(",", " ").split(), dtype=np.float64)


def _named(element: ET.Element, tag: str, name: str) -> str | None:
    found = element.find(f"{tag}[@name='{name}']")
    return None if found is None else found.get("value")


def _camera(sensor: ET.Element, aspect: float) -> Camera:
    """A Mitsuba ``perspective`` sensor (``fov_axis`` x, a ``lookat``) as a `Camera`;
    ``aspect`` is the image's width over its height."""
    look = sensor.find("transform/lookat")
    fov_x = float(_named(sensor, "float", "fov"))
    fov_y = np.degrees(2 * np.arctan(np.tan(np.radians(fov_x) / 2) / aspect))
    return Camera(origin=_floats(look.get("origin")), target=_floats(look.get("target")),
                  up=_floats(look.get("up")), fov_x=fov_x, fov_y=float(fov_y),
                  near=float(_named(sensor, "float", "near_clip")), far=float(_named(sensor, "float", "far_clip")))


def _ice(shape: ET.Element) -> IceShading:
    bsdf = shape.find("bsdf")
    ior = _named(bsdf, "string", "int_ior")
    ior = WATER_ICE_IOR if ior == "water ice" else float(_named(bsdf, "float", "int_ior"))
    tint = _named(bsdf, "rgb", "specular_transmittance")
    medium = shape.find("medium")
    absorption, scattering = np.zeros(3), 0.0
    if medium is not None:  # sigma_t (an RGB times a scale) and albedo: see `scene.mitsuba._medium_ice`
        extinction = _floats(_named(medium, "rgb", "sigma_t")) * float(_named(medium, "float", "scale"))
        albedo = _floats(_named(medium, "rgb", "albedo"))
        absorption, scattering = extinction * (1.0 - albedo), float(np.mean(extinction * albedo))
    return IceShading(ior=float(ior), alpha=float(_named(bsdf, "float", "alpha") or 0.0),
                      tint=tuple(_floats(tint)) if tint else (1.0, 1.0, 1.0),
                      absorption=tuple(float(a) for a in absorption), scattering=scattering,
                      flip=_named(shape, "boolean", "flip_normals") == "true")


def _view_names(job_dir: Path, count: int) -> tuple[str, ...]:
    """The views' names from ``views.json``; ``view<i>`` where it is missing or does not match."""
    try:
        names = [v["name"] for v in json.loads((job_dir / "views.json").read_text())]
    except (OSError, ValueError, KeyError, TypeError):
        names = []
    return tuple(names) if len(names) == count else tuple(f"view{i}" for i in range(count))
