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

from .artifacts import atomic_write
from .rendered import (TINT_DISTANCE_M, IceShading, Surface, object_surface, pbr, read_ice, read_rendered,
                       require)
from .scene.camera import world_frame

# Thickness hint of KHR_materials_volume (meters): a typical icicle's diameter. Viewers that
# refract by rasterising offset the background by it; path tracers use the real mesh.
ICE_THICKNESS_M = 0.02


def write_glb(job_dir: str | Path, out: str | Path) -> Path:
    """Write the object and the ice of a job that rendered as one GLB file at ``out``.

    Parameters
    ----------
    job_dir : path
        The job folder: ``ice.ply``, ``object.ply``, ``scene.xml``, ``params.yaml``.
    out : path
        The ``.glb`` file, written whole or not at all.

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
    require(job_dir, "ice.ply", "object.ply", "scene.xml", "params.yaml")
    rendered = read_rendered(job_dir)
    up = np.eye(4)
    up[:3, :3] = world_frame(rendered.gravity)  # rows right, up, front: to glTF's X, Y, Z
    scene = trimesh.Scene()
    look = pbr(rendered.material)
    obj_material = PBRMaterial(name="object", baseColorFactor=[*look.base_color, 1.0], metallicFactor=look.metallic,
                               roughnessFactor=look.roughness, doubleSided=True)  # rendered two-sided
    scene.add_geometry(_mesh(object_surface(job_dir), obj_material), node_name="object", geom_name="object",
                       transform=up)
    # Names to what trimesh cannot write: extensions, and base colours unrounded (it keeps 8 bits).
    matte = {} if look.specular else {"KHR_materials_specular": {"specularFactor": 0.0}}  # Mitsuba's diffuse
    finish = {"object": (look.base_color, matte)}
    if rendered.ice is not None:
        ice = rendered.ice
        ice_material = PBRMaterial(name="ice", baseColorFactor=[*ice.tint, 1.0], metallicFactor=0.0,
                                   roughnessFactor=ice.roughness, alphaMode="OPAQUE")
        scene.add_geometry(_mesh(read_ice(job_dir, ice.flip), ice_material), node_name="ice", geom_name="ice",
                           transform=up)
        finish["ice"] = (ice.tint, ice_extensions(ice))
    data = export_glb(scene, include_normals=True, tree_postprocessor=functools.partial(_finish, materials=finish))
    atomic_write(out, data)
    return out


def ice_extensions(ice: IceShading) -> dict:
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


def _mesh(surface: Surface, material: PBRMaterial) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(material=material))
    mesh.vertex_normals = surface.normals  # cached: trimesh would recompute them, slower and unweighted
    return mesh


def _finish(tree: dict, materials: dict) -> None:
    """Complete the materials of a glTF ``tree`` in place: ``materials`` maps a material's
    name to its linear RGB base colour ``(3,)`` and its extensions, listed in ``extensionsUsed``."""
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
