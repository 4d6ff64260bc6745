"""Render a finished job again with another render config, leaving the job as it was."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import trimesh

from ..artifacts import read_ice_mesh, trajectories_from_json
from ..errors import InputError
from ..jobdir import DONE, ICE, OBJECT, PARAMS, SCENE_XML, TRAJECTORIES, JobState, read_job
from ..placement import Placement

# Written first into a render's folder and removed last: a folder holding it is not a finished
# render (stopped, or still running), whatever images it has.
INCOMPLETE = "INCOMPLETE.txt"
# What marks a folder as a render of `render_again`'s, which a new render may clear.
RENDER_FILES = (INCOMPLETE, SCENE_XML)


def estimate_seconds(job_dir: Path, config) -> tuple[float, str] | None:
    """How long ``config`` will take to render ``job_dir``'s scene, from the job's own render
    scaled by the samples (pixels x spp x views), and the words that say so; None when the job
    recorded no render time. Denoising and the scene's load are in the job's time too, so
    this errs long for small frames."""
    try:
        scene = json.loads((job_dir / "scene.json").read_text())
        seconds = float(read_job(job_dir).stats["render_seconds"])
        width, height = scene["resolution"]
        spp, views = scene["sampling"]["spp"], len(scene["views"])
    except (OSError, KeyError, TypeError, ValueError):
        return None
    before = width * height * spp * views
    after = config.width * config.height * config.spp * len(config.views)
    if not (before > 0 and seconds > 0):
        return None
    return seconds * after / before, (f"from this job's own render, {width}x{height} at {spp} spp x {views} "
                                      f"view{'s' * (views != 1)}: {seconds:.1f} s")


def meshed_coarser(job_dir: Path, config) -> str | None:
    """What to say when ``config`` shows ``job_dir``'s ice in more pixels than the job meshed
    it for (``mesh_view_px`` in its ``timings.json``: a preview's coarser mesh shows its
    facets in a lookdev frame or an ice view), and how to mesh it again; None when the job's
    mesh holds up (or it recorded no view)."""
    from ..stages.surface import meshing_view

    stats = read_job(job_dir).stats
    meshed_px = stats.get("mesh_view_px")
    if not meshed_px:
        return None
    meshed = meshing_view(meshed_px, stats.get("mesh_ice_view", True))
    needed = meshing_view(config.resolution, any(v.frame == "ice" for v in config.views))
    if needed.share <= meshed.share:
        return None
    def view(v) -> str:
        return f"a {v.width}x{v.height} view " + ("with an ice view" if v.ice_view else "of the whole object")

    return (f"this job's ice was meshed for {view(meshed)} (its render config); "
            f"{config.name} shows it in {view(needed)}: facets and beaded tips may show. "
            f"For the full detail, run the job again with --render {config.name} (icefarm run; in a sweep, "
            f"render: {config.name} in the manifest; with its --cache, stages 1-3 are reused)")


def render_again(job_dir: Path, render: str, out_dir: Path, progress: bool = False,
                 report: Callable[[str], None] | None = None):
    """Render a finished job's object and ice again with another render config, into ``out_dir``.

    For a contact-sheet cell worth a final frame: nothing is recomputed and the job folder
    is left as it is; ``out_dir`` gets its own scenes (``scene.xml``, ``scene.pov`` and
    their meshes) and renders. Needs a job that rendered (its ``object.ply`` is the object
    in meters). Gravity and the object's material are those the job's scene records
    (``scene.json``, `icefarm.scene.read_scene_spec`); the cameras are framed anew for
    the config's views.

    Parameters
    ----------
    job_dir : Path
        A job folder with ``done.json``, ``params.yaml``, ``ice.ply``, ``object.ply`` and ``scene.xml``.
    render : str
        Render config name or YAML path.
    out_dir : Path
        Its own folder: an earlier render there (`RENDER_FILES`) is cleared first; a folder
        holding anything else is refused. It holds `INCOMPLETE` until the render is done.
    progress : bool
        Progress bar over long renders.
    report : callable, optional
        ``report(line)``: progress lines for a log.

    Returns
    -------
    icefarm.scene.render.RenderResult

    Raises
    ------
    InputError
        Not a finished job, a job that never rendered, a bad render config, or an ``out_dir``
        holding files that are not a render's.
    """
    from ..scene import read_scene_spec
    from ..scene.config import load_render_config
    from ..scene.render import render_job  # looked up here, at call time: tests stand in for it
    from ..scene.write import job_scene

    job_dir, out_dir = Path(job_dir), Path(out_dir)
    job = read_job(job_dir)
    if job.state is not JobState.DONE:
        raise InputError(f"{job_dir} is not a finished job (no {DONE}): run it first")
    for name in (PARAMS, ICE, OBJECT, SCENE_XML):
        if not (job_dir / name).is_file():
            raise InputError(f"{job_dir} has no {name}: only jobs that rendered can be rendered again "
                             "(run the job without --no-render)")
    if out_dir.resolve() == job_dir.resolve():
        raise InputError("render into a folder of its own, not the job folder: its files belong to the job")
    config = load_render_config(render)
    if out_dir.is_dir() and any(out_dir.iterdir()):
        if not any((out_dir / name).is_file() for name in RENDER_FILES):
            raise InputError(f"{out_dir} holds files that are not a render's: pick an empty or new folder with -o")
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / INCOMPLETE).write_text(f"icefarm render of {job_dir.resolve()} with {render}, started "
                                      f"{time.strftime('%Y-%m-%d %H:%M:%S')}: not finished (stopped or still "
                                      "running); render it again to finish\n")
    spec = read_scene_spec(job_dir)
    obj = trimesh.load(job_dir / OBJECT, process=False)
    obj.merge_vertices(merge_norm=True)  # object.ply splits vertices along creases
    ice = read_ice_mesh(job_dir / ICE)
    axes = trajectories_from_json(job_dir / TRAJECTORIES).points if (job_dir / TRAJECTORIES).is_file() else None
    scene = job_scene(obj, ice if isinstance(ice, trimesh.Trimesh) else None, spec.gravity,
                      material=spec.material, placement=job.stats.get("placement", Placement.HANGING.value),
                      impurity=float((job.params or {}).get("surface.impurity", 0.0)),  # 0 for jobs older than it
                      icicle_axes=axes)
    result = render_job(out_dir, config, scene, progress=progress, report=report)
    (out_dir / INCOMPLETE).unlink()
    return result
