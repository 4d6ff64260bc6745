"""The add-on's Blender types: its preferences (the icefarm executable), the panel's settings
and state, the ``icefarm.grow`` operator (modal from the panel, blocking from a script), the
Cancel operator and the panel in the 3D view's sidebar."""

import time

import bpy
import numpy as np
from mathutils import Vector

from .command import GrowError, find_executable
from .grow import Grow
from .scene import meters_per_unit

POLL_S = 0.1  # the modal operator's timer, and the blocking run's wait between polls


def _preferences(context):
    addon = context.preferences.addons.get(__package__)  # the add-on: its package
    return addon.preferences if addon is not None else None


class IcefarmPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__  # the add-on's name: its package, not this module

    executable: bpy.props.StringProperty(
        name="icefarm executable", subtype="FILE_PATH",
        description="The icefarm command (e.g. /path/to/repo/.venv/bin/icefarm); empty: the ICEFARM "
                    "environment variable, else icefarm on the PATH, else a .venv beside the add-on's repository")

    def draw(self, context):
        self.layout.prop(self, "executable")
        found = find_executable(self.executable)
        self.layout.label(text=f"runs: {found}" if found else "icefarm not found", icon="NONE" if found else "ERROR")


class IcefarmSettings(bpy.types.PropertyGroup):
    intensity: bpy.props.EnumProperty(
        name="Storm", default="moderate", description="storm.intensity: freezing-rain class by radial ice on a wire",
        items=[("light", "Light", "6 mm of radial ice"), ("moderate", "Moderate", "13 mm of radial ice"),
               ("severe", "Severe", "25 mm of radial ice")])
    kind: bpy.props.EnumProperty(
        name="Kind", default="freezing_rain", description="storm.kind",
        items=[("freezing_rain", "Freezing rain", "glaze on all the rain reaches, icicles at the drip rims"),
               ("meltwater", "Meltwater", "snow melting on the upper surfaces: long icicles at the eaves")])
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0, description="The job's random seed")
    placement: bpy.props.EnumProperty(
        name="Placement", default="ground", description="Where the object is",
        items=[("ground", "On the ground", "its lowest point rests on the ground; icicles stop at it"),
               ("hanging", "Hanging", "a sign, a branch, a lamp: the ground is below its ice")])
    render: bpy.props.BoolProperty(name="Render", default=False,
                                   description="Also render the job (slower); its folder is kept")
    render_config: bpy.props.StringProperty(name="Render config", default="preview",
                                            description="preview, lookdev, final, or a YAML path")
    settings: bpy.props.StringProperty(
        name="Settings", default="",
        description="More icefarm parameters, GROUP.PARAM=VALUE separated by spaces (icefarm params lists them)")
    job_folder: bpy.props.StringProperty(
        name="Job folder", subtype="DIR_PATH", default="",
        description="Keep each job's folder here (one per object); empty: a temporary folder, removed")


class IcefarmState(bpy.types.PropertyGroup):
    """The running grow, for the panel (not saved with the file)."""

    running: bpy.props.BoolProperty()
    progress: bpy.props.FloatProperty(min=0.0, max=1.0, subtype="FACTOR")
    status: bpy.props.StringProperty()
    cancel: bpy.props.BoolProperty()


_ACTIVE = []  # the Grow of the running modal operator, at most one


def _redraw(context):
    screen = getattr(context, "screen", None) or getattr(getattr(context, "window", None), "screen", None)
    for area in (screen.areas if screen else ()):
        if area.type == "VIEW_3D":
            area.tag_redraw()


class ICEFARM_OT_grow(bpy.types.Operator):
    """Grow ice on the selected meshes with icefarm, at their real size (scene units)"""

    bl_idname = "icefarm.grow"
    bl_label = "Grow ice"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT" and not _ACTIVE

    def _start(self, context):
        prefs = _preferences(context)
        executable = find_executable(prefs.executable if prefs else "")
        objects = sorted(context.selected_objects, key=lambda o: o.name)
        return Grow(context, objects, executable, context.scene.icefarm)

    def _finish(self, grow):
        for warning in grow.warnings:
            self.report({"WARNING"}, f"icefarm {warning}")
        self.report({"INFO"}, "; ".join(grow.summaries))
        return {"FINISHED"}

    def execute(self, context):
        """A script's call: every job to completion, blocking."""
        try:
            grow = self._start(context)
        except GrowError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        try:
            while not grow.step(context):
                time.sleep(POLL_S)
        except GrowError as exc:
            grow.cancel()
            self.report({"ERROR"}, str(exc) + _made(grow))
            return {"CANCELLED"} if not grow.made else {"FINISHED"}
        except BaseException:
            grow.cancel()
            raise
        grow.close()
        return self._finish(grow)

    def invoke(self, context, event):
        try:
            grow = self._start(context)
        except GrowError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        _ACTIVE.append(grow)
        state = context.window_manager.icefarm
        state.running, state.cancel, state.progress, state.status = True, False, 0.0, grow.text
        self._timer = context.window_manager.event_timer_add(POLL_S, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        grow, state = _ACTIVE[0], context.window_manager.icefarm
        if state.cancel:
            self._stop(context, grow)
            self.report({"WARNING"}, "icefarm cancelled: its process was stopped" + _made(grow))
            return {"CANCELLED"} if not grow.made else {"FINISHED"}
        try:
            finished = grow.step(context)
        except GrowError as exc:
            self._stop(context, grow)
            self.report({"ERROR"}, str(exc) + _made(grow))
            return {"CANCELLED"} if not grow.made else {"FINISHED"}
        state.progress, state.status = grow.fraction, grow.text
        _redraw(context)
        if not finished:
            return {"PASS_THROUGH"}
        self._stop(context, grow)
        return self._finish(grow)

    def cancel(self, context):
        """Blender ends the operator (quitting, loading a file): stop the job."""
        if _ACTIVE:
            self._stop(context, _ACTIVE[0])

    def _stop(self, context, grow):
        grow.cancel()
        if grow in _ACTIVE:
            _ACTIVE.remove(grow)
        context.window_manager.event_timer_remove(self._timer)
        state = context.window_manager.icefarm
        state.running, state.cancel, state.progress, state.status = False, False, 0.0, ""
        _redraw(context)


def _made(grow):
    return f" (ice was brought back on {', '.join(grow.made)})" if grow.made else ""


class ICEFARM_OT_cancel(bpy.types.Operator):
    """Stop the running icefarm job; its ice is not brought back"""

    bl_idname = "icefarm.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return bool(_ACTIVE)

    def execute(self, context):
        context.window_manager.icefarm.cancel = True
        return {"FINISHED"}


class ICEFARM_PT_grow(bpy.types.Panel):
    bl_label = "icefarm"
    bl_idname = "ICEFARM_PT_grow"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "icefarm"

    def draw(self, context):
        layout = self.layout
        state = context.window_manager.icefarm
        if state.running:
            layout.progress(factor=state.progress, type="BAR", text=state.status)
            layout.operator(ICEFARM_OT_cancel.bl_idname, icon="CANCEL")
            return
        settings = context.scene.icefarm
        column = layout.column()
        column.prop(settings, "intensity")
        column.prop(settings, "kind")
        column.prop(settings, "seed")
        column.prop(settings, "placement")
        column.prop(settings, "render")
        if settings.render:
            column.prop(settings, "render_config")
        column.prop(settings, "settings")
        column.prop(settings, "job_folder")
        active = context.active_object
        if active is not None and active.select_get() and active.type == "MESH":
            corners = np.array([active.matrix_world @ Vector(corner) for corner in active.bound_box])
            height = float(np.ptp(corners[:, 2])) * meters_per_unit(context.scene)
            column.label(text=f"{active.name}: about {height:.3g} m tall")
        layout.operator(ICEFARM_OT_grow.bl_idname, icon="FREEZE")


CLASSES = (IcefarmPreferences, IcefarmSettings, IcefarmState, ICEFARM_OT_grow, ICEFARM_OT_cancel, ICEFARM_PT_grow)
