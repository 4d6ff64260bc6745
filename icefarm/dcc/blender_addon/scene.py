"""Blender's side of a job: the object's real size from the scene, its export to the job's GLB,
and the job's ice brought back as a glass mesh parented to it, in place."""

import math

import bpy
import numpy as np
from mathutils import Matrix

from .command import GrowError

MATERIAL_NAME = "icefarm ice"
# The glass of icefarm's USD export (icefarm.scene.config and icefarm.export.looks): water
# ice's index of refraction, and white light through 10 cm of ice, exp(-(3.2, 1.0, 0.7) /m
# * 0.1 m), as the ice's colour.
ICE_IOR = 1.31
ABSORPTION_PER_M = (3.2, 1.0, 0.7)
TINT_DISTANCE_M = 0.1
# As icefarm.mesh.LEVEL_FRACTION: an object whose height is under this fraction of its
# largest extent lies flat, and icefarm reads size_m as that extent.
LEVEL_FRACTION = 1e-4


def meters_per_unit(scene):
    """Meters per Blender unit: the scene's unit scale (1 with the unit system None)."""
    units = scene.unit_settings
    return 1.0 if units.system == "NONE" else float(units.scale_length)


def world_bounds(obj, depsgraph):
    """``(lo, hi)``, the world-space bounding box of the vertices of ``obj``'s faces after
    its modifiers, Blender units; raises `GrowError` when it has none."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        if len(mesh.polygons) == 0:
            raise GrowError(f"{obj.name} has no faces: icefarm grows ice on a surface")
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        used = np.empty(len(mesh.loops), dtype=np.int64)
        mesh.loops.foreach_get("vertex_index", used)
    finally:
        evaluated.to_mesh_clear()
    matrix = np.array(obj.matrix_world)
    world = co.reshape(-1, 3)[np.unique(used)] @ matrix[:3, :3].T + matrix[:3, 3]
    return world.min(axis=0), world.max(axis=0)


def real_size(lo, hi, meters):
    """``size_m`` for icefarm: the box's height along Blender's Z in meters, or its largest
    extent when it lies flat; raises `GrowError` for a box of no size."""
    extents = (np.asarray(hi) - np.asarray(lo)) * meters
    largest = float(extents.max())
    if not largest > 0 or not math.isfinite(largest):
        raise GrowError("the object has no size: its faces lie on one point")
    height = float(extents[2])
    return height if height >= LEVEL_FRACTION * largest else largest


def job_to_world(centre, meters):
    """``(4, 4)`` Matrix from the job frame (the GLB's +Y up axes, meters, centred on the
    object's bounding box) to Blender's world (Z up, Blender units)."""
    axes = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))  # glTF (x, y, z) -> (x, -z, y)
    return Matrix.Translation(tuple(float(c) for c in centre)) @ Matrix.Scale(1.0 / meters, 4) @ axes


def export_glb(context, obj, path):
    """``obj`` alone, modifiers applied, at its world transform, to the GLB ``path``."""
    view_layer = context.view_layer
    selected = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    try:
        for other in selected:
            other.select_set(False)
        obj.select_set(True)
        view_layer.objects.active = obj
        bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", use_selection=True, export_apply=True,
                                  export_materials="NONE", export_animations=False, export_cameras=False,
                                  export_lights=False, export_extras=False, export_yup=True)
    except (AttributeError, RuntimeError) as exc:
        raise GrowError(f"cannot export {obj.name} to glTF (Blender's glTF 2.0 add-on must be on): "
                        f"{str(exc).strip()}") from None
    finally:
        obj.select_set(False)
        for other in selected:
            other.select_set(True)
        view_layer.objects.active = active


def glass_material():
    """The ice's glass, made once per file (``icefarm ice``)."""
    material = bpy.data.materials.get(MATERIAL_NAME)
    if material is not None and material.get("icefarm"):
        return material
    material = bpy.data.materials.new(MATERIAL_NAME)
    material["icefarm"] = True
    material.use_nodes = True
    bsdf = next((n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        bsdf = material.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
    tint = tuple(math.exp(-a * TINT_DISTANCE_M) for a in ABSORPTION_PER_M)
    bsdf.inputs["Base Color"].default_value = tint + (1.0,)
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["IOR"].default_value = ICE_IOR
    bsdf.inputs["Roughness"].default_value = 0.0
    material.diffuse_color = tint + (0.3,)  # the solid view's colour
    return material


def import_ice(context, path, target, to_local):
    """The ice mesh at ``path`` (job frame) as a glass object parented to ``target``, its
    vertices in ``target``'s frame (``to_local``: `job_to_world` followed by the inverse of
    ``target``'s world matrix when it was exported), smooth shaded, in ``target``'s collections."""
    view_layer = context.view_layer
    selected = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    before = set(bpy.data.objects)
    try:
        bpy.ops.wm.ply_import(filepath=str(path), forward_axis="Y", up_axis="Z", use_scene_unit=False)
    except RuntimeError as exc:
        raise GrowError(f"cannot import the ice of {target.name}: {str(exc).strip()}") from None
    new = [o for o in bpy.data.objects if o not in before]
    if len(new) != 1 or new[0].type != "MESH":
        for obj in new:
            bpy.data.objects.remove(obj)
        raise GrowError(f"the ice of {target.name} did not import as one mesh")
    ice = new[0]
    ice.name = ice.data.name = f"{target.name} ice"
    ice.data.transform(to_local)
    smooth = np.ones(len(ice.data.polygons), dtype=bool)
    ice.data.polygons.foreach_set("use_smooth", smooth)
    ice.data.materials.clear()
    ice.data.materials.append(glass_material())
    ice.parent = target
    ice.matrix_parent_inverse = Matrix.Identity(4)
    ice.matrix_basis = Matrix.Identity(4)
    ice.matrix_world = target.matrix_world.copy()  # now, not at the next depsgraph update
    for collection in list(ice.users_collection):
        collection.objects.unlink(ice)
    for collection in target.users_collection:
        collection.objects.link(ice)
    ice.select_set(False)
    for obj in selected:
        obj.select_set(True)
    view_layer.objects.active = active
    return ice
