"""icefarm as a library: grow ice on a mesh, get typed results, write or render them.

`grow` takes a `trimesh.Trimesh` (or a file, or ``generator:NAME``), a storm by name or by
values and a seed, runs the job as ``icefarm run`` does (`icefarm.job.pipeline.run_job`: the
same stages, the same figures, the same errors) and returns an `Ice`: the ice mesh, the
icicles with their roots, tips, lengths and axes, the storm's glaze per vertex of the
object, and the figures of ``timings.json``. `write` turns an `Ice` into a job folder that
``icefarm render`` and ``icefarm export`` read; `render` renders it with a render config.

Everything is in meters, in the job's frame: the object scaled to its real size and
centred on the origin (as ``ice.ply`` and ``--exclude`` have it). `Ice.input_transform`
takes it back to the frame and units of the mesh that was given.

Examples
--------
>>> import trimesh, icefarm
>>> ice = icefarm.grow(trimesh.creation.box((0.3, 0.3, 0.3)), placement="hanging")  # doctest: +SKIP
>>> ice.icicles.lengths  # doctest: +SKIP
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import trimesh

from . import artifacts
from .errors import InputError, cannot_write
from .job import Stage, Step, ancestors, cached_steps, run_stages
from .job.cache import StageCache, digest, write_policy
from .job.pipeline import JobSpec, load_object, mesh_digest, run_job
from .job.spec import IN_MEMORY, MeshInput, job_spec, mesh_source, write_input
from .job.stats import JobStats, write_record
from .jobdir import DONE, ERROR, ICE, PARAMS, TIMINGS, TRAJECTORIES, JobState, clear_job, read_job, stage_phrase
from .mesh import PreparedMesh
from .params import Params
from .stages.trajectories import TrajectoryResult
from .stages.trajectory_stats import measure_trajectories

if TYPE_CHECKING:
    from .scene.render import RenderResult
    from .scene.write import JobScene

__all__ = ["Ice", "Icicles", "MeshInput", "grow", "job_spec", "render", "write"]


@dataclass(frozen=True, eq=False)
class Icicles:
    """The icicles of a grown `Ice`: one per trunk of stage 3's trajectories that grew.

    Attributes
    ----------
    roots : (k, 3) float
        Where each icicle hangs from the object (its trunk's first point), meters.
    tips : (k, 3) float
        Each icicle's tip (its trunk's last point), meters: below its root along gravity.
    lengths : (k,) float
        Arc length of each trunk, meters (``timings.json``'s ``trunk_lengths_m``).
    trunks : (k,) int
        Each icicle's trunk: its branch index in `trajectories`.
    trajectories : TrajectoryResult
        Every branch's axis polyline, trunks and side branches, stored flat
        (`icefarm.stages.trajectories.TrajectoryResult`), meters; as ``trajectories.json``.
    """

    roots: npt.NDArray[np.float64]
    tips: npt.NDArray[np.float64]
    lengths: npt.NDArray[np.float64]
    trunks: npt.NDArray[np.int64]
    trajectories: TrajectoryResult

    def __len__(self) -> int:
        return len(self.trunks)

    def axis(self, i: int) -> npt.NDArray[np.float64]:
        """``(n, 3) float``: icicle ``i``'s trunk polyline, root to tip, meters."""
        return self.trajectories.branch(int(self.trunks[i]))

    @property
    def axes(self) -> list[npt.NDArray[np.float64]]:
        """Every icicle's trunk polyline (`axis`), ``(n_i, 3)`` meters each."""
        return [self.axis(i) for i in range(len(self))]

    @classmethod
    def from_trajectories(cls, trajectories: TrajectoryResult, gravity: npt.ArrayLike) -> Icicles:
        """The icicles of stage 3's ``trajectories``: the trunks (``branch_parent == -1``) of
        more than one point, as the job counts them (a drop that falls straight onto the
        object grows none).

        Parameters
        ----------
        trajectories : TrajectoryResult
            Polylines in meters.
        gravity : (3,) float
            Direction of gravity.
        """
        parent = np.asarray(trajectories.branch_parent, dtype=np.int64)
        offsets = np.asarray(trajectories.branch_offsets, dtype=np.int64)
        trunk = np.flatnonzero(parent < 0)
        grew = np.diff(offsets)[trunk] > 1
        lengths = measure_trajectories(trajectories, gravity).trunk_lengths[grew]
        trunks = trunk[grew]
        points = np.asarray(trajectories.points, dtype=np.float64).reshape(-1, 3)
        return cls(roots=points[offsets[trunks]], tips=points[offsets[trunks + 1] - 1],
                   lengths=np.asarray(lengths, dtype=np.float64), trunks=trunks, trajectories=trajectories)


@dataclass(frozen=True, eq=False, repr=False)
class Ice:
    """Ice grown on one object by `grow`: what a job computes, in memory.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        The ice (icicles, their bases, the glaze, ground ice), watertight, meters; as
        ``ice.ply``, with the ripples' bands in ``vertex_attributes`` where it has them.
    icicles : Icicles
        Roots, tips, lengths and axes of the icicles.
    glaze_thickness : (n,) float or None
        The storm's glaze per vertex of `object_mesh`, meters of ice: what the physical
        storm froze where its rain landed and ran (`icefarm.stages.storm.StormResult.ice`,
        taken from the nearest vertex of the surface the water ran on, a proxy or a refined
        copy of the object). None under ``storm.mode=relative`` or painted water.
    figures : dict
        The job's figures as ``timings.json`` holds them (icicles, ice faces, glaze
        coverage and percentiles, fringe, ripples, storm budget, ...), without its seconds.
    params : Params
        The resolved parameters the job ran with (``params.yaml``).
    object_mesh : trimesh.Trimesh
        The object as the stages saw it: cleaned, in meters, centred on the origin.
    seconds : dict
        Each step's time, seconds (``timings.json``'s ``seconds``).
    seed : int
    placement : {"ground", "hanging"}
    input_transform : (4, 4) float
        Takes the job's frame (meters, object centred) to the input mesh's frame and
        units: ``ice.mesh.copy().apply_transform(ice.input_transform)`` lies on the asset.
    name : str
        The object's id: the file's stem, the generator's name, or ``mesh``.
    """

    mesh: trimesh.Trimesh
    icicles: Icicles
    glaze_thickness: npt.NDArray[np.float64] | None
    figures: dict[str, Any]
    params: Params
    object_mesh: trimesh.Trimesh
    seconds: dict[str, float] = field(default_factory=dict)
    seed: int = 0
    placement: str = "ground"
    input_transform: npt.NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    name: str = IN_MEMORY

    @property
    def gravity(self) -> npt.NDArray[np.float64]:
        """``(3,) float`` unit vector: the direction water fell (``water.gravity``)."""
        return self.params.gravity

    def write(self, folder: str | os.PathLike[str], *, config: str | os.PathLike[str] = "preview") -> Path:
        """`write` this ice into ``folder``."""
        return write(self, folder, config=config)

    def render(self, folder: str | os.PathLike[str], config: str | os.PathLike[str] = "lookdev", *,
               material: Mapping[str, Any] | None = None, progress: bool = False) -> RenderResult:
        """`render` this ice into ``folder``."""
        return render(self, folder, config, material=material, progress=progress)

    def __repr__(self) -> str:
        glaze = self.figures.get("glaze_p50_mm")
        return (f"Ice({self.name}: {len(self.icicles)} icicles, {len(self.mesh.faces)} ice faces, "
                f"glaze p50 {'-' if glaze is None else f'{glaze:.1f} mm'}, seed {self.seed})")


def grow(mesh: MeshInput, *, size_m: float | None = None, storm: str | Mapping[str, Any] = "moderate",
         kind: str = "freezing_rain", params: Mapping[str, Any] | None = None, seed: int = 0,
         placement: str = "ground", exclude: Sequence[tuple[Sequence[float], Sequence[float]]] = (),
         cache: str | os.PathLike[str] | None = None, progress: bool = False) -> Ice:
    """Grow icicles and glaze on ``mesh`` under a storm, as ``icefarm run --no-render`` does.

    The job runs in a temporary folder (`icefarm.job.pipeline.run_job`: the same stages, cache
    keys, figures and failures as the command line) and is read back; nothing is left on
    disk. Write it with `write`, render it with `render`.

    Parameters
    ----------
    mesh : trimesh.Trimesh, path or str
        A mesh in memory, in meters with +Y up (``water.gravity`` in ``params`` says
        otherwise); the path of a file ``icefarm run`` reads (USD, glTF/GLB: their own
        units and up axis; OBJ, PLY, STL, OFF: give ``size_m``); or ``generator:NAME``.
    size_m : float, optional
        The object's real height along gravity, meters (its largest extent when it lies
        flat); the mesh is scaled to it. None: the size the mesh carries (a mesh in
        memory, USD, glTF, a real-size generator).
    storm : str or mapping
        An intensity, ``light``, ``moderate`` or ``severe`` (``storm.intensity``), or
        ``storm.*`` values, ``{"precipitation": 20, "wind": [0, 0, -8]}`` (the ``storm.``
        prefix optional; `icefarm params` lists them).
    kind : {"freezing_rain", "meltwater"}
        ``storm.kind``.
    params : mapping, optional
        Further ``"group.param": value`` overrides (or ``{group: {param: value}}``), laid
        last: their ``storm.*`` keys win over ``storm`` and ``kind``.
    seed : int
        Seed of the job's random streams: the same seed gives the same ice.
    placement : {"ground", "hanging"}
        ``ground``: the object stands on the ground (its sole stays dry, icicles stop at
        the ground); ``hanging``: a sign, a branch, a lamp.
    exclude : sequence of ((3,), (3,)) float
        Boxes, lowest and highest corners in meters in the job's frame (object centred),
        where no icicle hangs (``--exclude``).
    cache : path, optional
        A stage cache folder (``--cache``) to reuse stage results across calls.
    progress : bool
        Show the job's steps on stderr.

    Returns
    -------
    Ice

    Raises
    ------
    InputError
        Bad input, with the message ``icefarm run`` prints: a missing file, a mesh without
        units and no ``size_m``, an unknown storm, parameter or generator, a value out of
        its domain, a mesh with nothing to grow on; or a job that failed on its input.
    RuntimeError
        A job that failed otherwise (the stage and the traceback in its message's notes).
    """
    source, name, written = mesh_source(mesh)
    options: dict[str, Any] = dict(size_m=size_m, storm=storm, kind=kind, params=params, seed=seed, placement=placement,
                   exclude=exclude)
    with tempfile.TemporaryDirectory(prefix="icefarm-") as tmp:
        try:
            if written is not None:  # glTF carries meters and +Y up: the job keeps the mesh as it is
                source = str(write_input(written, Path(tmp)))
            spec = job_spec(source, **options, warn_stacklevel=3)
            if written is not None:
                spec = replace(spec, object_id=name)
            prepared = load_object(spec)  # a bad mesh fails here, in its own words
        except InputError as exc:
            if written is None:
                raise
            raise InputError(str(exc).replace(f"mesh {source}", "the mesh").replace(source, "the mesh")) from None
        if spec.params.growth.frames:
            raise InputError("growth.frames: grow() returns the full-grown ice; the frames are the job folder's "
                             "(icefarm run --growth-frames)")
        cache_dir = Path(cache) if cache is not None else Path(tmp) / "cache"
        if cache is None:
            # its own cache keeps the water and what it reads (the storm's glaze per vertex,
            # read back below, is not in the job folder); the other steps are not stored
            kept = {s.name for s in ancestors("water")}
            write_policy(cache_dir, [name for name in cached_steps() if name not in kept])
        job_dir = Path(tmp) / "job"
        outcome = run_job(spec, job_dir, cache_dir, progress=progress)
        if outcome.status is not JobState.DONE:
            _raise_failure(job_dir, outcome.failed_stage, outcome.error)
        job = read_job(job_dir)
        ice_mesh = artifacts.read_ice_mesh(job_dir / ICE)
        trajectories = artifacts.trajectories_from_json(job_dir / TRAJECTORIES)
        glaze = _glaze_thickness(spec, prepared, StageCache(cache_dir))
    if not isinstance(ice_mesh, trimesh.Trimesh):  # no ice at all reads back as an empty scene
        ice_mesh = trimesh.Trimesh()
    return Ice(mesh=ice_mesh, icicles=Icicles.from_trajectories(trajectories, spec.params.gravity),
               glaze_thickness=glaze, figures=dict(job.stats), params=spec.params, object_mesh=prepared.mesh,
               seconds=dict(job.seconds), seed=spec.seed, placement=spec.placement,
               input_transform=_input_transform(prepared), name=spec.object_id)


def write(ice: Ice, folder: str | os.PathLike[str], *, config: str | os.PathLike[str] = "preview") -> Path:
    """Write ``ice`` into ``folder`` as a finished job that ``icefarm render`` and ``icefarm
    export`` read: ``params.yaml``, ``ice.ply``, ``trajectories.json``, the scene of render
    config ``config`` without rendering it (``object.ply``, ``scene.json``, ``scene.xml``,
    ``scene.pov``, ``views.json``, the sky), ``timings.json`` and ``done.json`` last.

    What an earlier job wrote in ``folder`` is removed first (`icefarm.jobdir.clear_job`);
    other files stay. Stage 1-2's diagnostics (``water.ply``, ``drips.json``) are
    ``icefarm run``'s only.

    Parameters
    ----------
    ice : Ice
    folder : path
    config : str or path
        A render config name (``preview``, ``lookdev``, ``final``) or YAML path: the
        cameras and look the scene files are written with.

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    InputError
        A bad render config, or a folder that cannot be written.
    """
    from .scene.config import load_render_config
    from .scene.write import write_scenes

    render_config = load_render_config(config)
    scene = _scene(ice, None)
    folder = _job_folder(ice, folder)
    try:  # as `render_job` writes a job's scene, without rendering it
        write_scenes(folder, scene, render_config)
    except OSError as exc:
        raise cannot_write(exc, f"the job folder {folder}") from None
    _finish(ice, folder, {})
    return folder


def render(ice: Ice, folder: str | os.PathLike[str], config: str | os.PathLike[str] = "lookdev", *,
           material: Mapping[str, Any] | None = None, progress: bool = False) -> RenderResult:
    """Write ``ice`` into ``folder`` (as `write` does) and render it, as a job renders.

    The scene and the renders are `icefarm.scene.render.render_job`'s: ``render.exr``,
    ``render.png`` and one pair per further view of the config.

    Parameters
    ----------
    ice : Ice
    folder : path
    config : str or path
        A render config name (``preview``, ``lookdev``, ``final``) or YAML path.
    material : mapping, optional
        The object's material, ``{type, color, roughness, metal}``; default clay.
    progress : bool
        A progress bar over long renders.

    Returns
    -------
    icefarm.scene.render.RenderResult
        Timings, the renderer and variant, and the images (``files``, the main view's first).

    Raises
    ------
    InputError
        A bad render config or material, a renderer that cannot run here, or a folder that
        cannot be written.
    """
    from .scene.config import load_render_config
    from .scene.render import render_job

    render_config = load_render_config(config)
    scene = _scene(ice, material)  # a bad material fails before the folder is touched
    folder = _job_folder(ice, folder)
    result = render_job(folder, render_config, scene, progress=progress)
    _finish(ice, folder, {"render": round(result.seconds, 6)}, {
        "object_material": scene.material.to_dict(), "render_variant": result.variant,
        "render_integrator": result.integrator, "renderer": result.renderer, "render_seconds": result.seconds,
        "scene_seconds": result.scene_seconds})
    return result


# ---------------------------------------------------------------- grow's input
def _glaze_thickness(spec: JobSpec, prepared: PreparedMesh, cache: StageCache) -> npt.NDArray[np.float64] | None:
    """The storm's glaze per vertex of the object, from the job's water stage in ``cache``;
    None without a storm, or when the water is not there (not recomputed)."""
    class Missing(Exception):
        pass

    def cached(step: Step, key: str | None, work: Any) -> Any:
        def missing() -> Any:
            raise Missing(step.name)

        return cache.get(step.name, key, missing) if key else missing()

    p = spec.params
    try:  # the pipeline's mesh key (icefarm.job.pipeline.run_job), so the same entries are read
        r = run_stages(prepared, p, spec.seed, placement=spec.placement, exclude=spec.exclude, until=Stage.WATER,
                       mesh_key=digest(mesh_digest(spec.mesh), spec.size_m, p.water.gravity), step=cached)
    except Missing:
        return None
    storm = r.water.storm if r.water is not None else None
    if storm is None:
        return None
    ice = np.asarray(storm.ice, dtype=np.float64)
    obj = prepared.mesh
    if r.flow is obj:
        return ice
    from scipy.spatial import cKDTree

    return ice[cKDTree(r.flow.vertices).query(obj.vertices)[1]]


def _raise_failure(job_dir: Path, stage: str | None, message: str | None) -> None:
    """A failed job as an exception: its own `InputError` again, anything else a RuntimeError
    carrying the traceback."""
    error = read_job(job_dir)
    text = error.traceback or ""
    last = text.strip().splitlines()[-1] if text.strip() else ""
    if last.startswith(f"{InputError.__module__}.{InputError.__name__}:"):
        raise InputError(message)
    exc = RuntimeError(f"job failed {stage_phrase(stage)}: {message}")
    if hasattr(exc, "add_note"):  # Python 3.11 and later
        exc.add_note(f"the job's traceback (its {ERROR}):\n{text}")
    raise exc


def _input_transform(prepared: PreparedMesh) -> npt.NDArray[np.float64]:
    """``(4, 4)``: the job's frame back to the input's, ``(v + offset) / scale``."""
    matrix = np.eye(4) / prepared.scale
    matrix[3, 3] = 1.0
    matrix[:3, 3] = np.asarray(prepared.offset, dtype=np.float64) / prepared.scale
    return matrix


# ---------------------------------------------------------------- write's and render's folder
def _scene(ice: Ice, material: Mapping[str, Any] | None) -> JobScene:
    """The `JobScene` of ``ice``, framed as the pipeline frames a job's."""
    from .scene.write import job_scene

    return job_scene(ice.object_mesh, ice.mesh, ice.gravity, material=material, placement=ice.placement,
                     impurity=ice.params.surface.impurity, icicle_axes=ice.icicles.trajectories.points)


def _job_folder(ice: Ice, folder: str | os.PathLike[str]) -> Path:
    """``folder`` cleared of an earlier job's files (as `run_job` clears it), with this
    job's parameters, ice and trajectories."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
        clear_job(path)
        artifacts.write_yaml(path / PARAMS, ice.params.as_dict())
        artifacts.write_mesh(path / ICE, ice.mesh)
        artifacts.write_json(path / TRAJECTORIES, artifacts.trajectories_to_json(ice.icicles.trajectories))
    except OSError as exc:
        raise cannot_write(exc, f"the job folder {path}") from None
    return path


def _finish(ice: Ice, folder: Path, seconds: dict[str, float], figures: Mapping[str, Any] | None = None) -> None:
    """The job's ``timings.json`` and, last, ``done.json`` listing every file."""
    stats = JobStats({**ice.seconds, **seconds}, {**ice.figures, **(figures or {})})
    stats.write(folder / TIMINGS)
    write_record(folder / DONE, {"job": ice.name, **stats.as_json(), "artifacts": artifacts.list_artifacts(folder)})
