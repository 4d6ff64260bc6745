"""``scene.json``: a job's rendered scene described once, for every writer and reader.

`SceneSpec` is the scene as a renderer-agnostic record: the image size and sampling, the
views and their cameras, the world frame (from gravity), the sky, the sun, the ground, the
object and its material, the ice and its look. `icefarm.scene.write.write_scenes` builds it
from a render config and a job's meshes, then renders it to each format: ``scene.xml``
(`icefarm.scene.mitsuba.scene_xml`), ``scene.pov`` (`icefarm.scene.povray.scene_pov`) and
``scene.json`` itself (`SceneSpec.to_json`), which the render's integrator, the USD and glTF
exports and ``icefarm render`` read back (`icefarm.scene.write.read_scene_spec`; jobs from
before it through `icefarm.scene.legacy`).

Lengths in meters, colours linear RGB, angles in degrees. The light keeps its terms as the
render config gave them (strengths, sun elevation, exposure) beside what they make (the
sky's scale, the sun's irradiance), so that a writer that approximates the sky (POV-Ray's
fill lights) computes what it always did. Version 1 files (no sampling, exposure, light
terms or ground square) still read; their missing values are None.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..jobdir import ICE_BANDS, SCENE_SPEC
from .camera import Camera
from .config import IceLook
from .material import Material, material_from_dict

SPEC_FILE = SCENE_SPEC  # scene.json, in the job folder (`icefarm.jobdir`)
SPEC_VERSION = 2
SUN_WARMTH = (1.0, 0.93, 0.84)  # the sun's colour (a late-morning white)
# GGX alpha of the milky bands (`IceLook.shimmer`): chosen by eye on the bench's and the
# table's ice views, where the ripples refracted the brown seat above as a zebra of dark
# stripes: at 0.3 they stayed; at 0.5 they blur into pale bands without painting the ice white.
BAND_ALPHA = 0.5
BAND_ATTRIBUTE = "vertex_" + ICE_BANDS.rsplit("_", 1)[0]  # that PLY property as Mitsuba names it


@dataclass(frozen=True)
class SpecView:
    """One view: its ``name``, what it ``frame`` s (``all`` or ``ice``) and ``icicle_px``, how
    wide (pixels) the densest icicles are in it (None where not measured)."""

    name: str
    frame: str = "all"
    icicle_px: float | None = None


@dataclass(frozen=True)
class Sampling:
    """How the renders sample: samples per pixel, path depth, denoiser (``none``, ``oidn``)."""

    spp: int
    max_depth: int
    denoise: str


@dataclass(frozen=True)
class Sky:
    """The environment image ``file`` (in the job folder), its radiance ``scale`` (``strength``
    times the exposure's gain), turned so that its local X, Y, Z are the world frame's rows."""

    file: str
    scale: float
    strength: float | None = None


@dataclass(frozen=True)
class Sun:
    """A directional sun: unit ``direction`` towards it, ``irradiance`` (W/m^2, Mitsuba's scale,
    the exposure's gain included), and the config's ``strength`` (W/m^2 before the gain and
    the warm tint) and ``elevation`` (degrees above the horizon)."""

    direction: np.ndarray
    irradiance: np.ndarray
    strength: float | None = None
    elevation: float | None = None


@dataclass(frozen=True)
class Ground:
    """The ground: a square of ``corners`` ``(4, 3)`` (counter-clockwise seen from above) of a
    matte ``color`` ``(3,)`` (a checker's mean), for every format; and for the renderers
    the square's ``centre``, ``half_size`` and checker ``cell`` (meters), its ``pattern``
    (``checker`` or ``plain``) and its ``colors`` (the checker's two, or the plain one).
    Those are None in version 1 files."""

    corners: np.ndarray
    color: np.ndarray
    centre: np.ndarray | None = None
    half_size: float | None = None
    cell: float | None = None
    pattern: str | None = None
    colors: tuple = ()

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.corners[1] - self.corners[0], self.corners[2] - self.corners[0])
        return n / np.linalg.norm(n)


def square_ground(centre: np.ndarray, half_size: float, cell: float, frame: np.ndarray, pattern: str,
                  colors: Sequence) -> Ground:
    """`Ground` of a square of ``half_size`` around ``centre`` in ``frame`` (rows right, up,
    front): corners as Mitsuba's rectangle has them (local X to front, Y to right, at +-1)."""
    right, _, front = np.asarray(frame, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)
    local = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    corners = centre + local[:, :1] * front * half_size + local[:, 1:] * right * half_size
    colors = tuple(tuple(float(c) for c in rgb) for rgb in colors)
    return Ground(corners=corners, color=np.mean(colors, axis=0), centre=centre, half_size=float(half_size),
                  cell=float(cell), pattern=pattern, colors=colors)


@dataclass(frozen=True)
class SceneSpec:
    """A job's rendered scene (see the module docstring).

    Attributes
    ----------
    resolution : (int, int)
        Width and height, pixels.
    views : tuple of SpecView
        One per camera, the main view first.
    cameras : tuple of Camera
    frame : (3, 3) float
        World frame rows right, up (minus gravity), front (`icefarm.scene.camera.world_frame`):
        the sky is turned to it and the ground lies along it.
    gravity : (3,) float
        Unit gravity.
    sky : Sky
    sun : Sun or None
        None without a sun.
    ground : Ground or None
        None without a ground.
    object_file : str
        The object's mesh, in the job folder.
    material : Material
        The object's validated material.
    ice : IceLook or None
        The ice's look as rendered (the job's impurity applied); None without ice.
    ice_file : str or None
        The ice's mesh, in the job folder; None without ice.
    ice_flip : bool
        The ice mesh's faces wind inwards (Mitsuba flips its normals; exports reverse them).
    exposure : float or None
        Stops every light is scaled by (None in version 1 files).
    sampling : Sampling or None
        None in version 1 files.
    """

    resolution: tuple[int, int]
    views: tuple[SpecView, ...]
    cameras: tuple[Camera, ...]
    frame: np.ndarray
    gravity: np.ndarray
    sky: Sky
    sun: Sun | None
    ground: Ground | None
    object_file: str
    material: Material
    ice: IceLook | None
    ice_file: str | None
    ice_flip: bool
    exposure: float | None = None
    sampling: Sampling | None = None

    @property
    def up(self) -> np.ndarray:
        return self.frame[1]

    def to_json(self) -> dict:
        """The JSON-ready ``scene.json``."""
        sun, ground, ice = self.sun, self.ground, self.ice
        return {
            "version": SPEC_VERSION,
            "resolution": [int(v) for v in self.resolution],
            "views": [{"name": v.name, "frame": v.frame, "icicle_px": v.icicle_px} for v in self.views],
            "cameras": [{"origin": _list(c.origin), "target": _list(c.target), "up": _list(c.up), "fov_x": c.fov_x,
                         "fov_y": c.fov_y, "near": c.near, "far": c.far} for c in self.cameras],
            "gravity": _list(self.gravity),
            "sky": {"file": self.sky.file, "scale": self.sky.scale, "frame": np.asarray(self.frame).tolist(),
                    "strength": self.sky.strength},
            "sun": None if sun is None else {  # the direction written as a unit vector
                "direction": _list(sun.direction / np.linalg.norm(sun.direction)), "irradiance": _list(sun.irradiance),
                "strength": sun.strength, "elevation": sun.elevation},
            "ground": None if ground is None else {
                "corners": np.asarray(ground.corners).tolist(), "color": _list(ground.color),
                "centre": None if ground.centre is None else _list(ground.centre), "half_size": ground.half_size,
                "cell": ground.cell, "pattern": ground.pattern, "colors": [list(c) for c in ground.colors]},
            "object": {"file": self.object_file, "material": self.material.to_dict()},
            "ice": None if ice is None else {
                "file": self.ice_file, "flip": bool(self.ice_flip), "ior": ice.ior, "alpha": ice.roughness,
                "tint": list(ice.tint), "absorption": list(ice.absorption), "scattering": ice.scattering,
                "shimmer": ice.shimmer},
            "exposure": self.exposure,
            "sampling": None if self.sampling is None else {
                "spp": self.sampling.spp, "max_depth": self.sampling.max_depth, "denoise": self.sampling.denoise},
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SceneSpec:
        """`SceneSpec` of a ``scene.json`` (version 1 or 2).

        Raises
        ------
        KeyError, TypeError, ValueError
            Not a ``scene.json`` written by icefarm.
        """
        sky, sun, ground, ice = data["sky"], data.get("sun"), data.get("ground"), data.get("ice")
        sampling = data.get("sampling")
        return cls(
            resolution=tuple(int(v) for v in data["resolution"]),
            views=tuple(SpecView(str(v["name"]), str(v.get("frame", "all")), v.get("icicle_px"))
                        for v in data["views"]),
            cameras=tuple(Camera(origin=np.asarray(c["origin"], dtype=np.float64),
                                 target=np.asarray(c["target"], dtype=np.float64),
                                 up=np.asarray(c["up"], dtype=np.float64), fov_x=float(c["fov_x"]),
                                 fov_y=float(c["fov_y"]), near=float(c["near"]), far=float(c["far"]))
                          for c in data["cameras"]),
            frame=np.asarray(sky["frame"], dtype=np.float64).reshape(3, 3),
            gravity=np.asarray(data["gravity"], dtype=np.float64).reshape(3),
            sky=Sky(str(sky["file"]), float(sky["scale"]), sky.get("strength")),
            sun=None if sun is None else Sun(np.asarray(sun["direction"], dtype=np.float64),
                                             np.asarray(sun["irradiance"], dtype=np.float64),
                                             sun.get("strength"), sun.get("elevation")),
            ground=None if ground is None else Ground(
                np.asarray(ground["corners"], dtype=np.float64).reshape(4, 3),
                np.asarray(ground["color"], dtype=np.float64),
                None if ground.get("centre") is None else np.asarray(ground["centre"], dtype=np.float64),
                ground.get("half_size"), ground.get("cell"), ground.get("pattern"),
                tuple(tuple(float(x) for x in c) for c in ground.get("colors") or ())),
            object_file=str(data["object"]["file"]),
            material=material_from_dict(data["object"]["material"]),
            ice=None if ice is None else IceLook(
                ior=float(ice["ior"]), roughness=float(ice["alpha"]), tint=tuple(float(t) for t in ice["tint"]),
                absorption=tuple(float(a) for a in ice["absorption"]), scattering=float(ice["scattering"]),
                shimmer=float(ice.get("shimmer", 0.0))),
            ice_file=None if ice is None else str(ice["file"]), ice_flip=ice is not None and bool(ice["flip"]),
            exposure=data.get("exposure"),
            sampling=None if sampling is None else Sampling(int(sampling["spp"]), int(sampling["max_depth"]),
                                                            str(sampling["denoise"])))


def sun_irradiance(environment) -> np.ndarray:
    """(3,) the sun's irradiance, W/m^2 in Mitsuba's scale: warm white times its strength
    and the exposure."""
    return np.asarray(SUN_WARMTH) * environment.sun_strength * 2.0 ** environment.exposure


def sky_scale(environment) -> float:
    """The sky image's radiance scale: its strength times the exposure."""
    return float(environment.sky_strength * 2.0 ** environment.exposure)


def write_spec(path: str | Path, spec: SceneSpec) -> None:
    from ..artifacts import atomic_write

    atomic_write(Path(path), json.dumps(spec.to_json(), indent=1) + "\n")


def read_spec(path: str | Path) -> SceneSpec:
    """The `SceneSpec` of a ``scene.json``.

    Raises
    ------
    OSError
        The file cannot be read.
    KeyError, TypeError, ValueError
        Not a ``scene.json`` written by icefarm.
    """
    return SceneSpec.from_json(json.loads(Path(path).read_text()))


def _list(v) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=np.float64).reshape(-1)]
