"""Render a finished job again with another render config, leaving the job as it was."""

from __future__ import annotations

from pathlib import Path

import trimesh

from ..artifacts import read_ice_mesh, trajectories_from_json
from ..errors import InputError
from ..jobdir import DONE, ICE, OBJECT, PARAMS, SCENE_XML, TRAJECTORIES, JobState, read_job
from ..placement import Placement


def render_again(job_dir: Path, render: str, out_dir: Path, progress: bool = False):
    """Render a finished job's object and ice again with another render config, into ``out_dir``.

    For a contact-sheet cell worth a final frame: nothing is recomputed and the job folder
    is left as it is; ``out_dir`` gets its own scenes (``scene.xml``, ``scene.pov`` and
    their meshes) and renders. Needs a job that rendered (its ``object.ply`` is the object
    in meters). Gravity and the object's material are those the job's scene records
    (``scene.json``, `icefarm.export.rendered.read_rendered`); the cameras are framed anew for
    the config's views.

    Parameters
    ----------
    job_dir : Path
        A job folder with ``done.json``, ``params.yaml``, ``ice.ply``, ``object.ply`` and ``scene.xml``.
    render : str
        Render config name or YAML path.
    out_dir : Path
    progress : bool
        Progress bar over long renders.

    Returns
    -------
    icefarm.scene.render.RenderResult

    Raises
    ------
    InputError
        Not a finished job, a job that never rendered, or a bad render config.
    """
    from .rendered import read_rendered
    from ..scene.config import load_render_config
    from ..scene.render import render_job
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
    rendered = read_rendered(job_dir)
    obj = trimesh.load(job_dir / OBJECT, process=False)
    obj.merge_vertices(merge_norm=True)  # object.ply splits vertices along creases
    ice = read_ice_mesh(job_dir / ICE)
    axes = trajectories_from_json(job_dir / TRAJECTORIES).points if (job_dir / TRAJECTORIES).is_file() else None
    scene = job_scene(obj, ice if isinstance(ice, trimesh.Trimesh) else None, rendered.gravity,
                      material=rendered.material, placement=job.stats.get("placement", Placement.HANGING.value),
                      impurity=float((job.params or {}).get("surface.impurity", 0.0)),  # 0 for jobs older than it
                      icicle_axes=axes)
    return render_job(out_dir, config, scene, progress=progress)
