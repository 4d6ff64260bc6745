"""A rendered job as one binary glTF (``.glb``) for viewers and game engines.

glTF is +Y up and in meters: the scene's root node turns the job's frame so that minus
gravity is +Y (`scene.camera.world_frame`: identity for the default gravity -Y), the
vertices stay those of ``object.ply`` and ``ice.ply``. The ice is a PBR material made of
transmission and refraction, as in the render:

- ``KHR_materials_transmission`` 1: what is not reflected passes through;
- ``KHR_materials_ior`` 1.31, water ice;
- ``KHR_materials_volume``: the ice's absorption as an attenuation colour at a distance
  (Beer-Lambert, as Mitsuba's medium), with a typical icicle's thickness for viewers
  that fake refraction; the per-crossing tint is the base colour.

trimesh writes the meshes and the core material but knows none of these extensions; its
exporter's ``tree_postprocessor`` hook adds them to the JSON tree before it is encoded,
so no GLB bytes are edited by hand.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.gltf import export_glb
from trimesh.visual.material import PBRMaterial

from ..artifacts import atomic_write
from ..jobdir import ICE, OBJECT, PARAMS, SCENE_XML
from ..scene import IceLook, SceneSpec, read_scene_spec, world_frame
from .looks import TINT_DISTANCE_M, pbr, perceptual_roughness, sun_light
from .meshes import Surface, object_surface, read_ice, require

# Thickness hint of KHR_materials_volume (meters): a typical icicle's diameter. Viewers that
# refract by rasterising offset the background by it; path tracers use the real mesh.
ICE_THICKNESS_M = 0.02


def write_glb(job_dir: str | Path, out: str | Path, max_faces: int | None = None) -> Path:
    """Write the object and the ice of a job that rendered as one GLB file at ``out``.

    Parameters
    ----------
    job_dir : path
        The job folder: ``ice.ply``, ``object.ply``, ``scene.xml``, ``params.yaml``.
    out : path
        The ``.glb`` file, written whole or not at all.
    max_faces : int, optional
        A light preview: the object and the ice are decimated (quadric edge collapse,
        `fast_simplification` through trimesh) to about this many faces together, shared
        by their face counts. Default: the meshes as rendered.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    InputError
        Not a job that rendered (names the missing file).
    """
    job_dir, out = Path(job_dir), Path(out)
    require(job_dir, ICE, OBJECT, SCENE_XML, PARAMS)
    spec = read_scene_spec(job_dir)
    up = np.eye(4)
    up[:3, :3] = world_frame(spec.gravity)  # rows right, up, front: to glTF's X, Y, Z
    scene = trimesh.Scene()
    look = pbr(spec.material)
    obj_material = PBRMaterial(name="object", baseColorFactor=[*look.base_color, 1.0], metallicFactor=look.metallic,
                               roughnessFactor=look.roughness, doubleSided=True)  # rendered two-sided
    obj_surface = object_surface(job_dir)
    ice_surface = read_ice(job_dir, spec.ice_flip) if spec.ice is not None else None
    if max_faces is not None:
        obj_surface, ice_surface = _decimated((obj_surface, ice_surface), max_faces)
    scene.add_geometry(_mesh(obj_surface, obj_material), node_name="object", geom_name="object",
                       transform=up)
    # Names to what trimesh cannot write: extensions, and base colours unrounded (it keeps 8 bits).
    matte = {} if look.specular else {"KHR_materials_specular": {"specularFactor": 0.0}}  # Mitsuba's diffuse
    finish = {"object": (look.base_color, matte)}
    if spec.ice is not None:
        ice = spec.ice
        ice_material = PBRMaterial(name="ice", baseColorFactor=[*ice.tint, 1.0], metallicFactor=0.0,
                                   roughnessFactor=perceptual_roughness(ice.roughness), alphaMode="OPAQUE")
        scene.add_geometry(_mesh(ice_surface, ice_material), node_name="ice", geom_name="ice",
                           transform=up)
        finish["ice"] = (ice.tint, ice_extensions(ice))
    if spec.ground is not None:
        ground = spec.ground
        if max_faces is not None:  # a preview frames the object: its ground a little wider than it
            ground = _ground_around(ground, np.vstack([obj_surface.vertices] + (
                [ice_surface.vertices] if ice_surface is not None else [])))
        ground_material = PBRMaterial(name="ground", baseColorFactor=[*map(float, ground.color), 1.0],
                                      metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True)
        quad = trimesh.Trimesh(ground.corners, [[0, 1, 2], [0, 2, 3]], process=False,
                               visual=trimesh.visual.TextureVisuals(material=ground_material))
        scene.add_geometry(quad, node_name="ground", geom_name="ground", transform=up)
        finish["ground"] = (ground.color, {"KHR_materials_specular": {"specularFactor": 0.0}})
    data = export_glb(scene, include_normals=True, tree_postprocessor=functools.partial(
        _finish, materials=finish, spec=spec, frame=up[:3, :3]))
    atomic_write(out, data)
    return out


def ice_extensions(ice: IceLook) -> dict:
    """The glTF material extensions of the ice: transmission, ior and, when the ice
    absorbs, volume (``attenuationColor`` is what white light keeps after
    ``attenuationDistance`` meters)."""
    out = {"KHR_materials_transmission": {"transmissionFactor": 1.0},
           "KHR_materials_ior": {"ior": round(ice.ior, 6)}}
    if max(ice.absorption) > 0:
        color = np.exp(-np.asarray(ice.absorption) * TINT_DISTANCE_M)
        out["KHR_materials_volume"] = {"thicknessFactor": ICE_THICKNESS_M, "attenuationDistance": TINT_DISTANCE_M,
                                       "attenuationColor": [round(float(c), 6) for c in color]}
    return out


def _ground_around(ground, points: np.ndarray, margin: float = 1.5):
    """``ground`` cut to a square ``margin`` times the half-width of ``points`` (n, 3)
    around them: the render's ground reaches 15 sizes out, which a viewer that frames the
    whole scene shows as a plane with a dot on it."""
    import dataclasses

    corners = np.asarray(ground.corners, dtype=np.float64)
    centre = corners.mean(axis=0)
    normal = ground.normal
    middle = points.mean(axis=0)
    middle = middle - ((middle - centre) @ normal) * normal  # on the ground plane
    half = margin * float(np.linalg.norm(points - points.mean(axis=0), axis=1).max())
    scale = half / (0.5 * float(np.linalg.norm(corners[1] - corners[0])))
    return dataclasses.replace(ground, corners=middle + (corners - centre) * min(scale, 1.0))


def _decimated(surfaces: tuple, max_faces: int) -> tuple:
    """``surfaces`` (Surface or None) with at most about ``max_faces`` faces in all, each
    keeping its share; normals recomputed on the decimated meshes."""
    total = sum(len(s.faces) for s in surfaces if s is not None)
    if total <= max_faces:
        return surfaces
    out = []
    for surface in surfaces:
        if surface is None or len(surface.faces) < 8:
            out.append(surface)
            continue
        mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False)
        target = max(4, int(max_faces * len(surface.faces) / total))
        light = mesh.simplify_quadric_decimation(face_count=target)
        out.append(Surface(np.asarray(light.vertices, dtype=np.float32), np.asarray(light.faces, dtype=np.int32),
                           np.asarray(light.vertex_normals, dtype=np.float32)))
    return tuple(out)


def _mesh(surface: Surface, material: PBRMaterial) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(material=material))
    mesh.vertex_normals = surface.normals  # cached: trimesh would recompute them, slower and unweighted
    return mesh


def _finish(tree: dict, materials: dict, spec: SceneSpec | None = None, frame: np.ndarray | None = None) -> None:
    """Complete a glTF ``tree`` in place.

    ``materials`` maps a material's name to its linear RGB base colour ``(3,)`` and its
    extensions, listed in ``extensionsUsed``. With the job's ``spec`` and ``frame``
    (``(3, 3)``: world to glTF axes), the rendered cameras and the sun
    (``KHR_lights_punctual``) join the scene. The asset names icefarm as its generator and
    every bufferView its target (vertex data or indices).
    """
    from .. import __version__

    tree.setdefault("asset", {})["generator"] = f"icefarm {__version__}"
    _buffer_targets(tree)
    if spec is not None and frame is not None:
        _cameras_and_sun(tree, spec, frame)
    used = set(tree.get("extensionsUsed", []))
    for material in tree.get("materials", []):
        if material.get("name") not in materials:
            continue
        color, extensions = materials[material["name"]]
        material.setdefault("pbrMetallicRoughness", {})["baseColorFactor"] = [*map(float, color), 1.0]
        if extensions:
            material.setdefault("extensions", {}).update(extensions)
            used.update(extensions)
    if used:
        tree["extensionsUsed"] = sorted(used)


ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


def _buffer_targets(tree: dict) -> None:
    """Each bufferView of a mesh's vertex attributes gets target ``ARRAY_BUFFER``, of its
    indices ``ELEMENT_ARRAY_BUFFER``."""
    views = tree.get("bufferViews", [])
    accessors = tree.get("accessors", [])
    for mesh in tree.get("meshes", []):
        for primitive in mesh.get("primitives", []):
            pairs = [(a, ARRAY_BUFFER) for a in primitive.get("attributes", {}).values()]
            if "indices" in primitive:
                pairs.append((primitive["indices"], ELEMENT_ARRAY_BUFFER))
            for accessor, target in pairs:
                view = accessors[accessor].get("bufferView")
                if view is not None:
                    views[view]["target"] = target


def _quaternion(columns: np.ndarray) -> list[float]:
    """glTF's ``[x, y, z, w]`` of the rotation whose matrix has ``columns`` ``(3, 3)``."""
    m = np.eye(4)
    m[:3, :3] = columns
    w, x, y, z = trimesh.transformations.quaternion_from_matrix(m)
    return [float(x), float(y), float(z), float(w)]


def _cameras_and_sun(tree: dict, spec: SceneSpec, frame: np.ndarray) -> None:
    """The rendered views as glTF cameras (looking down their local -Z, +Y up) and the sun
    as a ``KHR_lights_punctual`` directional light (shining down its local -Z; intensity:
    Mitsuba's irradiance, W/m^2), each on a node of the default scene."""
    nodes = tree.setdefault("nodes", [])
    scene = tree["scenes"][tree.get("scene", 0)].setdefault("nodes", [])
    cameras = tree.setdefault("cameras", [])
    width, height = spec.resolution
    for camera, name in zip(spec.cameras, (v.name for v in spec.views)):
        forward = frame @ camera.forward
        right = np.cross(forward, frame @ np.asarray(camera.up))
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        cameras.append({"name": name, "type": "perspective", "perspective": {
            "yfov": float(np.radians(camera.fov_y)), "aspectRatio": width / height,
            "znear": float(max(camera.near, 1e-4)), "zfar": float(camera.far)}})
        nodes.append({"name": f"camera_{name}", "camera": len(cameras) - 1,
                      "translation": [float(v) for v in frame @ camera.origin],
                      "rotation": _quaternion(np.column_stack([right, up, -forward]))})
        scene.append(len(nodes) - 1)
    sun = sun_light(spec)
    if sun is not None:
        towards, strength, color = sun
        z = frame @ towards  # local +Z towards the sun
        x = np.cross((0.0, 1.0, 0.0) if abs(z[1]) < 0.9 else (1.0, 0.0, 0.0), z)
        x /= np.linalg.norm(x)
        light = {"name": "sun", "type": "directional", "intensity": strength, "color": [float(c) for c in color]}
        tree.setdefault("extensions", {}).setdefault("KHR_lights_punctual", {}).setdefault("lights", []).append(light)
        nodes.append({"name": "sun", "rotation": _quaternion(np.column_stack([x, np.cross(z, x), z])),
                      "extensions": {"KHR_lights_punctual": {"light": 0}}})
        scene.append(len(nodes) - 1)
        tree["extensionsUsed"] = sorted(set(tree.get("extensionsUsed", [])) | {"KHR_lights_punctual"})
