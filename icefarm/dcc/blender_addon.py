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
``icefarm`` on the PATH, else the one in a ``.venv`` beside the repository this file sits in.

How one object's job goes:

1. Its evaluated mesh (modifiers applied) is exported alone to a temporary GLB with
   Blender's glTF exporter, at its world transform. glTF is +Y up, so the job's gravity is
   Blender's -Z. The exporter writes Blender units as meters whatever the unit scale, so the
   command passes ``--size-m``: the world bounding box's height in meters (its largest
   extent for an object lying flat, as icefarm reads ``size_m``).
2. ``icefarm run GLB -o FOLDER --no-render --size-m H --seed S --set storm.intensity=...``
   (``--render CONFIG`` instead when asked) runs with stdout and stderr piped. icefarm
   writes plain progress lines to a pipe (`icefarm.progress`, ``LINES`` mode): ``water ...``
   as a step starts, ``water done in 0.7 s`` as it ends; `Progress` weighs the steps.
3. The job's ``ice.ply`` is imported. It is in meters, in the GLB's axes, centred on the
   bounding box's centre (icefarm's job frame), so `job_to_world` maps it back: glTF's axes
   to Blender's, meters to Blender units, the centre back. Its vertices are stored in the
   object's frame as it was exported and the ice is parented to the object with an identity
   parent inverse: it sits where it grew, and an object moved while its ice grew, or later,
   takes its ice along.

Why ``ice.ply`` and not the job's ``ice.usdc``: a ``--no-render`` job (the fast one an
artist waits for) writes no USD, only ``ice.ply``; the PLY importer needs neither ``pxr``
nor the USD hook (`blender_usd_hook`), and the PLY is exactly the job frame mapped back
above. The glass is a Principled BSDF as the hook makes it from the USD's MaterialX:
transmission 1, IOR 1.31 (water ice), roughness 0, and the colour of the ice's absorption
through `TINT_DISTANCE_M` of ice as its base colour.

Install: Edit > Preferences > Add-ons > the menu at the top right > Install from Disk, pick
this file, enable "icefarm"; set the icefarm executable in its preferences if it is not on
the PATH. See docs/export.md.
"""

import math
import os
import queue
import re
import shlex
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

bl_info = {
    "name": "icefarm",
    "author": "icefarm",
    "description": "Grows icicles and glaze ice on the selected objects at their real size (runs icefarm)",
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > icefarm",
    "category": "Object",
}

ENVIRONMENT_VARIABLE = "ICEFARM"
# The job folder's ice (icefarm.jobdir.ICE: Blender's Python cannot import icefarm).
ICE_FILE = "ice.ply"
INPUT_FILE = "input.glb"
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
# A job's steps (icefarm.job.pipeline) and their rough share of its time, from an icefarm run
# on a 1 m cube and a 0.3 m bunny: the surface (meshing the ice) and a render dominate.
STEP_WEIGHTS = {"prepare": 1, "proxy": 1, "water": 2, "drips": 1, "trajectories": 1, "surface": 8, "measure": 2}
RENDER_STEP_WEIGHTS = {"render": 10, "usd": 1}
POLL_S = 0.1  # the modal operator's timer, and the blocking run's wait between polls
STOP_WAIT_S = 3.0  # how long a cancelled job has to end on SIGTERM before SIGKILL
STORM_INTENSITIES = ("light", "moderate", "severe")
STORM_KINDS = ("freezing_rain", "meltwater")
PLACEMENTS = ("ground", "hanging")


class GrowError(Exception):
    """What the operator reports as its one ERROR line: bad input, or a job that failed."""


# ---------------------------------------------------------------- the icefarm command
def find_executable(preference=""):
    """The icefarm command to run: ``preference`` (the add-on's preference), else the
    ``ICEFARM`` environment variable, else ``icefarm`` on the PATH, else a ``.venv``
    beside the repository holding this file; None when there is none."""
    for named in (preference, os.environ.get(ENVIRONMENT_VARIABLE, "")):
        if named:
            return bpy.path.abspath(named) if named.startswith("//") else named
    found = shutil.which("icefarm")
    if found:
        return found
    repo = Path(__file__).resolve().parents[2]
    for candidate in (repo / ".venv" / "bin" / "icefarm", repo / ".venv" / "Scripts" / "icefarm.exe"):
        if candidate.is_file():
            return str(candidate)
    return None


def setting_assignments(text):
    """The panel's extra settings, ``storm.max_icicles=8 surface.voxel_size=0.003`` (as
    ``--set`` takes them, separated by spaces), as a list of ``GROUP.PARAM=VALUE``."""
    try:
        words = shlex.split(text or "")
    except ValueError as exc:
        raise GrowError(f"icefarm settings {text!r}: {exc}") from None
    for word in words:
        if "=" not in word or "." not in word.partition("=")[0]:
            raise GrowError(f"icefarm setting {word!r}: expected GROUP.PARAM=VALUE (icefarm params lists them)")
    return words


@dataclass(frozen=True)
class JobOptions:
    """What the panel asks of every job: the storm, the seed, the placement, more settings
    and the render.

    Attributes
    ----------
    intensity, kind : str
        ``storm.intensity`` (`STORM_INTENSITIES`) and ``storm.kind`` (`STORM_KINDS`).
    seed : int
    placement : {"ground", "hanging"}
    settings : tuple of str
        More ``GROUP.PARAM=VALUE`` for ``--set``; they come last and win.
    render : str or None
        A render config (``preview``, ``lookdev``, ``final`` or a YAML path); None: no render.
    """

    intensity: str
    kind: str
    seed: int
    placement: str
    settings: tuple = ()
    render: str | None = None


def job_options(settings):
    """The `JobOptions` of the panel's ``settings`` (``scene.icefarm``); raises `GrowError`
    for extra settings that are not ``GROUP.PARAM=VALUE``."""
    return JobOptions(intensity=settings.intensity, kind=settings.kind, seed=settings.seed,
                      placement=settings.placement, settings=tuple(setting_assignments(settings.settings)),
                      render=settings.render_config if settings.render else None)


def job_command(executable, mesh, out, size_m, options):
    """The ``icefarm run`` command line of one job (a list for `subprocess.Popen`).

    Parameters
    ----------
    executable, mesh, out : str
        The icefarm command, the exported object, the job folder.
    size_m : float
        The object's real height in meters (``--size-m``).
    options : JobOptions
        The storm, seed, placement, more settings and render the panel asks for.
    """
    command = [str(executable), "run", str(mesh), "-o", str(out), "--size-m", repr(float(size_m)),
               "--seed", str(int(options.seed)), "--placement", options.placement,
               "--set", f"storm.intensity={options.intensity}", "--set", f"storm.kind={options.kind}"]
    for assignment in options.settings:
        command += ["--set", assignment]
    command += ["--render", options.render] if options.render else ["--no-render"]
    return command


def job_error(stderr, returncode):
    """The failed job's one-line message: the last ``error:`` line icefarm wrote to stderr,
    else its last line, else its exit status."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    if errors:
        return "icefarm " + errors[-1]
    if lines:
        return f"icefarm failed (exit status {returncode}): {lines[-1]}"
    return f"icefarm failed with exit status {returncode} and no message"


class Progress:
    """A job's progress from its stdout lines (icefarm's ``LINES`` progress mode).

    ``feed`` each line: ``NAME ...`` starts a step, ``NAME done in S s`` ends it,
    ``  NAME: text`` says what the current step is doing; the summary's ``  ice: ...`` line
    is kept. ``fraction`` is the weighted share of the steps done, below 1 until `finish`.
    """

    _END = re.compile(r"^(\S+) (done in|failed after) [0-9.]+ s$")

    def __init__(self, render=False):
        self.weights = dict(STEP_WEIGHTS, **(RENDER_STEP_WEIGHTS if render else {}))
        self.done = []
        self.step = self.detail = self.summary = ""
        self.finished = False

    def feed(self, line):
        text = line.rstrip("\r\n")
        if text.startswith("  "):
            name, _, detail = text.strip().partition(": ")
            if name == "ice" and detail:
                self.summary = text.strip()
            elif name == self.step and detail:
                self.detail = detail
            return
        end = self._END.match(text)
        if end:
            self.done.append(end.group(1))
            self.step = self.detail = ""
        elif text.endswith(" ...") and " " not in text[:-4]:
            self.step, self.detail = text[:-4], ""

    def finish(self):
        self.finished = True

    @property
    def fraction(self):
        if self.finished:
            return 1.0
        total = sum(self.weights.values())
        done = sum(self.weights.get(name, 0) for name in set(self.done))
        return min(done / total, 0.99)

    @property
    def text(self):
        if self.finished:
            return "done"
        if not self.step:
            return f"{self.done[-1]} done" if self.done else "starting"
        return ": ".join(part for part in (self.step, self.detail) if part)


class IcefarmProcess:
    """One running ``icefarm run``: its stdout and stderr read by two threads so that
    polling never blocks Blender, and a `cancel` that ends it and its children."""

    def __init__(self, command, render=False):
        self.command = list(command)
        self.progress = Progress(render)
        self._lines = queue.Queue()
        self._stderr = []
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "PYTHONPATH")}  # Blender's
        options = {"start_new_session": True} if os.name == "posix" else {
            "creationflags": getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0)}
        try:
            self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True, encoding="utf-8",
                                            errors="replace", bufsize=1, env=env, **options)
        except OSError as exc:
            raise GrowError(f"cannot run icefarm ({self.command[0]}): {exc.strerror or exc}; set its path in "
                            "the icefarm add-on's preferences or the ICEFARM environment variable") from None
        self._threads = [threading.Thread(target=self._read, args=(self.process.stdout, self._lines.put), daemon=True),
                         threading.Thread(target=self._read, args=(self.process.stderr, self._stderr.append),
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    @property
    def pid(self):
        return self.process.pid

    @staticmethod
    def _read(stream, put):
        for line in stream:
            put(line)
        stream.close()

    def poll(self):
        """Read what the job wrote since; None while it runs, else its exit status."""
        returncode = self.process.poll()
        if returncode is not None:
            for thread in self._threads:  # the pipes' last lines
                thread.join(timeout=5.0)
        while True:
            try:
                self.progress.feed(self._lines.get_nowait())
            except queue.Empty:
                break
        if returncode == 0:
            self.progress.finish()
        return returncode

    @property
    def stderr(self):
        return "".join(self._stderr)

    def warnings(self):
        return [line.strip() for line in self._stderr if line.startswith("warning:")]

    def cancel(self):
        """End the job and everything it started (its process group), SIGTERM first."""
        if self.process.poll() is None:  # (a finished job's group id may belong to another by now)
            self._signal(signal.SIGTERM)
            try:
                self.process.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                pass
            self._signal(getattr(signal, "SIGKILL", signal.SIGTERM))  # it, or children left in its group
            self.process.wait()
        for thread in self._threads:
            thread.join(timeout=5.0)

    def _signal(self, signum):
        if os.name == "posix":
            try:
                os.killpg(self.process.pid, signum)
            except (ProcessLookupError, PermissionError):
                pass
        elif self.process.poll() is None:
            subprocess.run(["taskkill", "/F", "/T", "/PID", str(self.process.pid)], capture_output=True)


# ---------------------------------------------------------------- Blender's side
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


class Job:
    """One object's job: its exported GLB, command, folder and where its ice goes back."""

    def __init__(self, context, obj, executable, settings, folder):
        self.object_name = obj.name
        self.folder = Path(folder)
        depsgraph = context.evaluated_depsgraph_get()
        lo, hi = world_bounds(obj, depsgraph)
        meters = meters_per_unit(context.scene)
        self.size_m = real_size(lo, hi, meters)
        # the ice in the object's frame as it was exported: moved meanwhile, the ice follows it
        self.to_local = obj.matrix_world.inverted() @ job_to_world((lo + hi) / 2, meters)
        self.mesh = self.folder / INPUT_FILE
        self.out = Path(bpy.path.abspath(settings.job_folder)) / bpy.path.clean_name(obj.name) \
            if settings.job_folder else self.folder / "job"
        options = job_options(settings)
        self.render = options.render
        self.command = job_command(executable, self.mesh, self.out, self.size_m, options)
        self.process = None

    def export(self, context):
        export_glb(context, bpy.data.objects[self.object_name], self.mesh)

    def start(self):
        self.process = IcefarmProcess(self.command, render=bool(self.render))

    def bring_back(self, context):
        target = bpy.data.objects.get(self.object_name)
        if target is None:
            raise GrowError(f"{self.object_name} was deleted while its ice grew")
        path = self.out / ICE_FILE
        if not path.is_file():
            raise GrowError(f"the job of {self.object_name} finished without its ice ({path})")
        return import_ice(context, path, target, self.to_local)

    @property
    def kept(self):
        """Whether the job folder stays: a job folder was set, or the job rendered."""
        return bool(self.render) or self.out.parent != self.folder


class Grow:
    """Every selected object's job, run one after another: the modal operator calls `step`
    on its timer, a script's call in a loop. Nothing is made in Blender until a job ends."""

    def __init__(self, context, objects, executable, settings):
        if not objects:
            raise GrowError("select one or more mesh objects to grow ice on")
        for obj in objects:
            if obj.type != "MESH":
                raise GrowError(f"{obj.name} is a {obj.type.lower()}, not a mesh: icefarm grows ice on meshes")
            if abs(obj.matrix_world.determinant()) < 1e-30:
                raise GrowError(f"{obj.name} has a zero scale: its ice could not follow it")
        if not executable:
            raise GrowError("icefarm not found: set its path in the icefarm add-on's preferences "
                            "(Edit > Preferences > Add-ons > icefarm) or the ICEFARM environment variable")
        self.folder = Path(tempfile.mkdtemp(prefix="icefarm-blender-"))
        self.jobs, self.made, self.warnings, self.summaries = [], [], [], []
        self.index = 0
        try:
            for number, obj in enumerate(objects):
                job = Job(context, obj, executable, settings, self.folder / str(number))
                job.folder.mkdir()
                self.jobs.append(job)
            for job in self.jobs:
                job.export(context)
        except BaseException:
            self.close()
            raise

    @property
    def fraction(self):
        if self.index >= len(self.jobs):
            return 1.0
        process = self.jobs[self.index].process
        return (self.index + (process.progress.fraction if process else 0.0)) / len(self.jobs)

    @property
    def text(self):
        if self.index >= len(self.jobs):
            return "done"
        job = self.jobs[self.index]
        status = job.process.progress.text if job.process else "starting"
        return f"{job.object_name} ({self.index + 1}/{len(self.jobs)}): {status}"

    def step(self, context):
        """Start, poll, or bring back the current job; True once every job is back.
        Raises `GrowError` for a failed job."""
        if self.index >= len(self.jobs):
            return True
        job = self.jobs[self.index]
        if job.process is None:
            job.start()
        returncode = job.process.poll()
        if returncode is None:
            return False
        self.warnings += job.process.warnings()
        if returncode != 0:
            raise GrowError(job_error(job.process.stderr, returncode))
        self.made.append(job.bring_back(context).name)
        summary = job.process.progress.summary
        self.summaries.append(f"{job.object_name}: {summary or 'ice'}" + (f" (job in {job.out})" if job.kept else ""))
        self.index += 1
        return self.index >= len(self.jobs)

    def cancel(self):
        """Stop the running job (nothing of it is brought back) and remove the temporary files."""
        if self.index < len(self.jobs) and self.jobs[self.index].process is not None:
            self.jobs[self.index].process.cancel()
        self.close()

    def close(self):
        keep = [job for job in self.jobs if job.kept and job.out.is_relative_to(self.folder)]
        if not keep:
            shutil.rmtree(self.folder, ignore_errors=True)
        else:  # a rendered job in the temporary folder: keep its folder, drop the inputs
            for job in self.jobs:
                job.mesh.unlink(missing_ok=True)


# ---------------------------------------------------------------- the add-on's types
def _preferences(context):
    addon = context.preferences.addons.get(__name__)
    return addon.preferences if addon is not None else None


class IcefarmPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__

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


if __name__ == "__main__":
    register()
