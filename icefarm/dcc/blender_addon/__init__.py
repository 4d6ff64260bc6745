"""Blender add-on: grow icefarm's ice on the selected objects from the 3D view's sidebar.

The panel (View3D > Sidebar (N) > icefarm) takes a storm (intensity and kind), a seed and a
placement; the objects' real size comes from the scene: their world-space bounding box in
Blender units times the scene's unit scale. Its operator, ``icefarm.grow``
(``bpy.ops.icefarm.grow``), runs ``icefarm run`` in a separate process, one job per
selected mesh, and brings each job's ice back as a glass mesh parented to its object, in
place. From the panel it is modal: a progress bar read from the job's progress lines and a
Cancel button that stops the process, while Blender stays responsive. Called from a script
(``EXEC_DEFAULT``) it runs to completion and returns. Errors go to Blender's report line:
the job's own one-line ``error:`` message.

Blender's Python does not have icefarm: the add-on imports only ``bpy``, ``mathutils``,
``numpy`` (bundled with Blender) and the standard library, and runs the ``icefarm``
command named in its preferences, else the ``ICEFARM`` environment variable, else
``icefarm`` on the PATH, else the one in a ``.venv`` beside the repository this package sits in.

The package's modules, each imported by the ones after it:

- `command`: finding the icefarm command, a job's ``icefarm run`` command line
  (`command.JobOptions`), a failed job's message, `command.GrowError`;
- `process`: one job as a separate process, its progress lines and its cancel;
- `scene`: Blender's side: the object's real size, its export, the ice brought back as glass;
- `grow`: each selected object's job, run one after another;
- `ui`: the preferences, the panel's settings and state, the operators and the panel.

This module holds ``bl_info`` (Blender reads it from the package's ``__init__.py``) and
registers `ui`'s classes.

How one object's job goes:

1. Its evaluated mesh (modifiers applied) is exported alone to a temporary GLB with
   Blender's glTF exporter, at its world transform. glTF is +Y up, so the job's gravity is
   Blender's -Z. The exporter writes Blender units as meters whatever the unit scale, so the
   command passes ``--size-m``: the world bounding box's height in meters (its largest
   extent for an object lying flat, as icefarm reads ``size_m``).
2. ``icefarm run GLB -o FOLDER --no-render --size-m H --seed S --set storm.intensity=...``
   (``--render CONFIG`` instead when asked) runs with stdout and stderr piped. icefarm
   writes plain progress lines to a pipe (`icefarm.progress`, ``LINES`` mode): ``water ...``
   as a step starts, ``water done in 0.7 s`` as it ends; `process.Progress` weighs the steps.
3. The job's ``ice.ply`` is imported. It is in meters, in the GLB's axes, centred on the
   bounding box's centre (icefarm's job frame), so `scene.job_to_world` maps it back: glTF's axes
   to Blender's, meters to Blender units, the centre back. Its vertices are stored in the
   object's frame as it was exported and the ice is parented to the object with an identity
   parent inverse: it sits where it grew, and an object moved while its ice grew, or later,
   takes its ice along.

Why ``ice.ply`` and not the job's ``ice.usdc``: a ``--no-render`` job (the fast one an
artist waits for) writes no USD, only ``ice.ply``; the PLY importer needs neither ``pxr``
nor the USD hook (`blender_usd_hook`), and the PLY is exactly the job frame mapped back
above. The glass is a Principled BSDF as the hook makes it from the USD's MaterialX:
transmission 1, IOR 1.31 (water ice), roughness 0, and the colour of the ice's absorption
through `scene.TINT_DISTANCE_M` of ice as its base colour.

Install: ``icefarm dcc blender-addon -o icefarm_blender.zip`` writes this package as a zip
(`icefarm.dcc.addon_zip`; the package ``icefarm_blender`` inside); then Edit > Preferences >
Add-ons > the menu at the top right > Install from Disk, pick the zip, enable "icefarm"; set
the icefarm executable in its preferences if it is not on the PATH. See docs/export.md.
"""

import bpy

from . import command, grow, process, scene, ui
from .ui import _ACTIVE, CLASSES, IcefarmSettings, IcefarmState

__all__ = ["bl_info", "command", "grow", "process", "register", "scene", "ui", "unregister"]

bl_info = {
    "name": "icefarm",
    "author": "icefarm",
    "description": "Grows icicles and glaze ice on the selected objects at their real size (runs icefarm)",
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > icefarm",
    "category": "Object",
}


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.icefarm = bpy.props.PointerProperty(type=IcefarmSettings)
    bpy.types.WindowManager.icefarm = bpy.props.PointerProperty(type=IcefarmState)


def unregister():
    while _ACTIVE:
        _ACTIVE.pop().cancel()
    del bpy.types.WindowManager.icefarm
    del bpy.types.Scene.icefarm
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
