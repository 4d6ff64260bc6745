"""Blender USD import hook: icefarm's ice arrives as glass, not as a faint shell.

Blender 5.0's USD importer reads only UsdPreviewSurface, which has no transmission: the
ice comes in with transmission 0 and alpha 0.1. icefarm's ``scene.usda`` also binds a
MaterialX network to the ice (OpenPBR Surface, or standard_surface) as its ``mtlx``
surface; this hook reads it on import and turns the material's Principled BSDF into
glass: transmission 1, the ior, the roughness, the colour of the ice's absorption, opaque
blending.

Install (it imports only ``bpy`` and the standard library):

- Blender: Edit > Preferences > Add-ons > Install from Disk, pick this file, enable it; or
  run it once from the Text Editor (it registers on run).
- ``bpy`` as a Python module: ``import blender_usd_hook; blender_usd_hook.register()``
  before ``bpy.ops.wm.usd_import(...)``. ``register()`` first puts Blender's bundled
  ``pxr`` on ``sys.path`` (the Blender application has it there already), without which
  the import aborts as soon as a hook receives a UsdShade material.
"""

import os
import sys

import bpy

bl_info = {
    "name": "icefarm ice from USD",
    "description": "Imports icefarm's MaterialX ice (OpenPBR / standard_surface) as glass",
    "blender": (4, 2, 0),
    "category": "Import-Export",
}

# MaterialX surface nodes the hook understands, and the inputs it reads from each:
# (transmission, ior, roughness, transmission colour).
_NODES = {
    "ND_open_pbr_surface_surfaceshader": ("transmission_weight", "specular_ior", "specular_roughness",
                                          "transmission_color"),
    "ND_standard_surface_surfaceshader": ("transmission", "specular_IOR", "specular_roughness",
                                          "transmission_color"),
}


def _bundled_pxr_path():
    """``bpy/<version>/python/lib/python3.x/site-packages`` beside the ``bpy`` package (Blender's
    own resources), when its ``pxr`` is there (None otherwise)."""
    local = bpy.utils.resource_path("LOCAL")
    python = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    path = os.path.join(local, "python", "lib", python, "site-packages")
    return path if os.path.isdir(os.path.join(path, "pxr")) else None


def _mtlx_surface(usd_material):
    """The prim of the MaterialX surface shader bound to ``usd_material`` (a
    UsdShade.Material, as the importer hands it) and its node id, or (None, None)."""
    output = usd_material.GetSurfaceOutput("mtlx")
    if not output:
        return None, None
    sources = output.GetConnectedSources()[0] if hasattr(output, "GetConnectedSources") else []
    for source in sources:
        prim = source.source.GetPrim()
        node = prim.GetAttribute("info:id").Get()
        if node in _NODES:
            return prim, node
    return None, None


def _value(shader_prim, name, default):
    """The shader's input ``name`` (its ``inputs:`` attribute), or ``default`` unset."""
    attribute = shader_prim.GetAttribute("inputs:" + name)
    value = attribute.Get() if attribute else None
    return default if value is None else value


def _principled(bl_material):
    bl_material.use_nodes = True
    for node in bl_material.node_tree.nodes:
        if node.type == "BSDF_PRINCIPLED":
            return node
    return bl_material.node_tree.nodes.new("ShaderNodeBsdfPrincipled")


class IcefarmIceHook(bpy.types.USDHook):
    """Turns a MaterialX ice surface into a glass Principled BSDF on USD import."""

    bl_idname = "icefarm_ice_hook"
    bl_label = "icefarm ice"
    bl_description = "MaterialX OpenPBR / standard_surface transmission to a glass Principled BSDF"

    @staticmethod
    def material_import_poll(context, usd_material):
        return _mtlx_surface(usd_material)[0] is not None

    @staticmethod
    def on_material_import(context, bl_material, usd_material):
        shader, node = _mtlx_surface(usd_material)
        if shader is None:
            return False
        transmission, ior, roughness, color = _NODES[node]
        bsdf = _principled(bl_material)
        bsdf.inputs["Transmission Weight"].default_value = float(_value(shader, transmission, 1.0))
        bsdf.inputs["IOR"].default_value = float(_value(shader, ior, 1.31))
        bsdf.inputs["Roughness"].default_value = float(_value(shader, roughness, 0.0))
        tint = tuple(float(c) for c in _value(shader, color, (1.0, 1.0, 1.0)))
        bsdf.inputs["Base Color"].default_value = tint + (1.0,)
        bsdf.inputs["Alpha"].default_value = 1.0  # the preview surface's 0.1 makes a faint shell
        # (setting surface_render_method here crashes Blender 5.0's importer: left as imported)
        return True


def register():
    path = _bundled_pxr_path()
    if path and path not in sys.path:
        sys.path.insert(0, path)
    bpy.utils.register_class(IcefarmIceHook)


def unregister():
    bpy.utils.unregister_class(IcefarmIceHook)


if __name__ == "__main__":
    register()
