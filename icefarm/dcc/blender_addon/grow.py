"""A grow: every selected object's job (export, ``icefarm run``, the ice brought back), run one
after another, and the temporary folder they work in."""

import shutil
import tempfile
from pathlib import Path

import bpy

from .command import GrowError, job_command, job_error, job_options
from .process import IcefarmProcess
from .scene import export_glb, import_ice, job_to_world, meters_per_unit, real_size, world_bounds

# The job folder's ice (icefarm.jobdir.ICE: Blender's Python cannot import icefarm).
ICE_FILE = "ice.ply"
INPUT_FILE = "input.glb"


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
