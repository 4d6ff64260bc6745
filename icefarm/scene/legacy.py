"""The `SceneSpec` of a job from before ``scene.json``, read back from its ``scene.xml``.

Only the scene package parses a renderer's file: `icefarm.scene.write.read_scene_spec` calls
`spec_from_xml` for such a job and supplies what the XML does not hold (gravity, the
object's material, the views' names). The XML is icefarm's own (`icefarm.scene.mitsuba`):
sensors with a ``lookat``, an ``envmap`` and a ``directional`` emitter, ``ply`` shapes
``object`` and ``ice`` (its dielectric and medium), the ``ground`` rectangle.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..jobdir import SCENE_XML
from .camera import Camera
from .config import IceLook
from .material import Material
from .mitsuba import WATER_ICE_IOR
from .spec import Ground, SceneSpec, Sky, SpecView, Sun


def spec_from_xml(path: str | Path, *, gravity, material: Material, view_names: Sequence[str] | None) -> SceneSpec:
    """What ``scene.xml`` at ``path`` renders, as a `SceneSpec` (no sampling, exposure or light
    terms: the XML keeps only their products).

    Parameters
    ----------
    gravity : (3,) float
        The job's gravity (normalised here).
    material : Material
        The object's material.
    view_names : sequence of str or None
        The views' names (``views.json``); ``view<i>`` when None or not one per sensor.

    Raises
    ------
    ValueError
        Not a ``scene.xml`` written by icefarm (the message says what is wrong).
    """
    try:
        root = ET.parse(path).getroot()
        defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
        width, height = int(defaults["resx"]), int(defaults["resy"])
        cameras = tuple(_camera(s, width / height) for s in root.iter("sensor"))
        emitters = {e.get("type"): e for e in root.iter("emitter")}
        envmap, sun = emitters["envmap"], emitters.get("directional")
        shapes = {s.get("id"): s for s in root.iter("shape")}
        frame = _floats(envmap.find("transform/matrix").get("value")).reshape(4, 4)[:3, :3].T
        names = list(view_names or ())
        if len(names) != len(cameras):
            names = [f"view{i}" for i in range(len(cameras))]
        g = np.asarray(gravity, dtype=np.float64)
        ice, ice_file, ice_flip = _ice(shapes["ice"]) if "ice" in shapes else (None, None, False)
        return SceneSpec(
            resolution=(width, height), views=tuple(SpecView(n) for n in names), cameras=cameras, frame=frame,
            gravity=g / np.linalg.norm(g),
            sky=Sky(_named(envmap, "string", "filename"), float(_named(envmap, "float", "scale") or 1.0)),
            sun=None if sun is None else Sun(-_floats(_named(sun, "vector", "direction")),
                                             _floats(_named(sun, "rgb", "irradiance"))),
            ground=_ground(shapes.get("ground")), object_file=_named(shapes["object"], "string", "filename"),
            material=material, ice=ice, ice_file=ice_file, ice_flip=ice_flip)
    except (ET.ParseError, KeyError, AttributeError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a {SCENE_XML} written by icefarm ({exc})") from None


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


def _ground(shape) -> Ground | None:
    """`Ground` from the ``rectangle`` shape (Mitsuba's square -1..1 in its local XY)."""
    if shape is None:
        return None
    m = _floats(shape.find("transform/matrix").get("value")).reshape(4, 4)
    local = np.array([[-1.0, -1.0, 0.0, 1.0], [1.0, -1.0, 0.0, 1.0], [1.0, 1.0, 0.0, 1.0], [-1.0, 1.0, 0.0, 1.0]])
    colors = [_floats(c.get("value").replace(",", " ")) for c in shape.iter("rgb")]
    return Ground(corners=(local @ m.T)[:, :3], color=np.mean(colors, axis=0) if colors else np.full(3, 0.1))


def _ice(shape: ET.Element) -> tuple[IceLook, str, bool]:
    """The ice's look, its mesh file and whether its faces are flipped."""
    bsdf = shape.find("bsdf")
    shimmer = 0.0
    if bsdf.get("type") == "blendbsdf":  # milky bands: the clear surface is the first of the two
        shimmer = float(_named(bsdf.find("texture[@name='weight']"), "float", "scale"))
        bsdf = bsdf.find("bsdf")
    ior = _named(bsdf, "string", "int_ior")
    ior = WATER_ICE_IOR if ior == "water ice" else float(_named(bsdf, "float", "int_ior"))
    tint = _named(bsdf, "rgb", "specular_transmittance")
    medium = shape.find("medium")
    absorption, scattering = np.zeros(3), 0.0
    if medium is not None:  # sigma_t (an RGB times a scale) and albedo: see `scene.mitsuba._medium_ice`
        extinction = _floats(_named(medium, "rgb", "sigma_t")) * float(_named(medium, "float", "scale"))
        albedo = _floats(_named(medium, "rgb", "albedo"))
        absorption, scattering = extinction * (1.0 - albedo), float(np.mean(extinction * albedo))
    look = IceLook(ior=float(ior), roughness=float(_named(bsdf, "float", "alpha") or 0.0),
                   tint=tuple(_floats(tint)) if tint else (1.0, 1.0, 1.0),
                   absorption=tuple(float(a) for a in absorption), scattering=scattering, shimmer=shimmer)
    return look, _named(shape, "string", "filename"), _named(shape, "boolean", "flip_normals") == "true"
