"""Write a job's scenes: ``scene.xml`` (Mitsuba 3), ``scene.pov`` (POV-Ray 3.7) with its mesh
includes, the meshes, the sky, ``scene.json`` (`icefarm.scene.spec`) and ``views.json``; and read
the scene back from a job folder (`read_scene_spec`).

`icefarm.scene.render` renders what is written here.
"""

from __future__ import annotations

import functools
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from .. import jobdir as jd
from ..artifacts import write_mesh
from ..errors import InputError
from ..spatial import ray_caster
from . import camera as cam, geometry as geo, mitsuba as mx, povray as pov
from .config import GROUND_CHECKER, GROUND_PLAIN, RenderConfig, ice_at_impurity
from .focus import ice_focus, pixel_size, surface_points, zoom_on_ice
from .images import write_exr
from .legacy import spec_from_xml
from .material import Material, material_from_dict
from .sky import procedural_sky
from .spec import (
    Ground,
    Sampling,
    SceneSpec,
    Sky,
    SpecView,
    Sun,
    read_spec,
    sky_scale,
    square_ground,
    sun_irradiance,
    write_spec,
)

CREASE_ANGLE = 30.0  # degrees: sharper edges of the object stay sharp in shading


@dataclass(frozen=True)
class SceneFiles:
    """What `write_scenes` wrote into a job folder, and the spec it wrote it from.

    Attributes
    ----------
    xml, pov : Path
        ``scene.xml`` (Mitsuba 3) and ``scene.pov`` (POV-Ray 3.7).
    object_ply, ice_ply : Path
        Meshes the XML names (``ice_ply`` None without ice).
    sky : Path
        Environment image.
    spec : SceneSpec
        The scene every file was written from (``scene.json``).
    seconds : float
        Time taken to write everything written before `write_scenes` returned.
    povray_writer : callable or None
        Writes the POV-Ray files, when `write_scenes` was told to defer them: `render_job`
        runs it in a thread once Mitsuba has loaded its scene. None once they are written.
    ice_normals : (n, 3) float or None
        The ice's unit vertex normals, for its faces as ``ice.ply`` winds them (not flipped),
        computed once by `write_spec_files` (`geometry.smooth_normals`: the angle-weighted
        normals Mitsuba computes when it loads ``ice.ply``), for ``ice.inc`` and the USD
        export. None without ice.
    """

    xml: Path
    pov: Path
    object_ply: Path
    ice_ply: Path | None
    sky: Path
    spec: SceneSpec
    seconds: float
    povray_writer: Callable[[], None] | None = None
    ice_normals: np.ndarray | None = None

    @property
    def cameras(self) -> tuple[cam.Camera, ...]:
        """One per view, the main view first."""
        return self.spec.cameras

    @property
    def icicle_px(self) -> tuple[float | None, ...]:
        """Per view, how wide (pixels) the densest icicles are in it; None where not measured
        (no ice view configured, or no icicles)."""
        return tuple(v.icicle_px for v in self.spec.views)

    @property
    def ground_height(self) -> float | None:
        """Height of the ground plane along -gravity, meters (None: no ground)."""
        ground = self.spec.ground
        return None if ground is None else float(ground.centre @ self.spec.up)


@dataclass(frozen=True)
class JobScene:
    """What a job's scene is made of, whatever writes (`write_scenes`) or renders it
    (`icefarm.scene.render.render_job`).

    Attributes
    ----------
    object_mesh : trimesh.Trimesh
        The object, meters.
    ice_mesh : trimesh.Trimesh or None
        The ice, meters (watertight); None renders the object alone.
    gravity : (3,) float
        Gravity direction: "up" is its opposite.
    material : Material
        The object's (`material.material_from_dict`); diffuse clay by default.
    frame_points : (n, 3) float or None
        What the cameras frame and the ground lies under, meters (`camera.frame_boxes`);
        None: the object's and the ice's vertices. The same points for every job of a
        sweep give identical cameras.
    impurity : float
        The job's ``surface.impurity`` in [0, 1]: the ice's scattering (its cloudy core)
        is the config's ``ice.scattering`` times this; 0 gives clear ice.
    ground_level : float or None
        Height (m, along minus gravity) of the ground plane: the lowest point of an
        object standing on it. None: just below the lowest framed point.
    icicle_axes : (k, 3) float or None
        Points along the icicles' axes (meters; the trajectories' points): an ice view
        frames ice near them, not glaze thicker than its reach (`focus.ice_focus`).
        None: ice far enough from the object counts as icicles.
    """

    object_mesh: trimesh.Trimesh
    ice_mesh: trimesh.Trimesh | None = None
    gravity: np.ndarray | Sequence[float] = (0.0, -1.0, 0.0)
    material: Material = field(default_factory=Material)
    frame_points: np.ndarray | None = None
    impurity: float = 0.0
    ground_level: float | None = None
    icicle_axes: np.ndarray | None = None


def job_scene(object_mesh: trimesh.Trimesh, ice_mesh: trimesh.Trimesh | None, gravity, *,
              material: Material | Mapping | None = None, placement: str = "ground",
              impurity: float = 0.0, icicle_axes: np.ndarray | None = None) -> JobScene:
    """The `JobScene` of a job: the cameras frame the boxes of the object and the ice, the
    ground lies under the object when it stands on it (`icefarm.placement.ground_level`).
    Ice without faces counts as none; ``icicle_axes`` (the trajectories' points) tell the
    ice views icicles from thick glaze."""
    from ..placement import ground_level

    ice = ice_mesh if ice_mesh is not None and len(ice_mesh.faces) else None
    return JobScene(object_mesh, ice, gravity, material_from_dict(material),
                    cam.frame_boxes(object_mesh, ice_mesh if ice_mesh is not None else trimesh.Trimesh()),
                    float(impurity), ground_level(placement, object_mesh, gravity), icicle_axes)


def _check_mesh(mesh: trimesh.Trimesh, what: str) -> None:
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{what} must be a trimesh.Trimesh with faces")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"{what} has non-finite vertices")


@functools.lru_cache(maxsize=8)
def _procedural_sky_exr(azimuth: float, elevation: float) -> bytes:
    """The EXR file of a procedural sky, made once per process: every job of a sweep shares it."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sky.exr"
        write_exr(path, procedural_sky(512, 256, azimuth, elevation), half=True)
        return path.read_bytes()


def write_scenes(job_dir: str | Path, scene: JobScene, config: RenderConfig, *,
                 defer_povray: bool = False) -> SceneFiles:
    """Write ``object.ply``, ``scene.xml``, ``scene.pov`` (+ includes), the sky,
    ``scene.json`` (the scene for every other writer, `icefarm.scene.spec`) and
    ``views.json`` into ``job_dir``.

    ``ice.ply`` is the pipeline's: it is written from ``scene.ice_mesh`` only when missing.

    Parameters
    ----------
    job_dir : path
        The job folder (created if missing).
    scene : JobScene
        The object, the ice, gravity, the object's material, what the cameras frame, the
        ice's impurity, the ground's level and the icicles' axes.
    config : RenderConfig
    defer_povray : bool
        Leave the POV-Ray files (``scene.pov``, ``object.inc``, ``ice.inc``: tens of
        megabytes of text for million-face ice) to ``SceneFiles.povray_writer``, which
        `render_job` runs alongside Mitsuba's render. Default: written before returning.

    ``views.json`` lists each view: ``index``, ``name``, ``frame`` (``all`` or ``ice``),
    ``stem`` (its image files' stem) and ``icicle_px``, the width in pixels of the
    densest icicles in it (null where not measured).

    Returns
    -------
    SceneFiles

    Raises
    ------
    InputError
        A bad material.
    ValueError
        Empty meshes, a zero gravity, an impurity outside [0, 1], frame points that are not
        finite or a ground level that is not finite.
    """
    start = time.perf_counter()
    spec = build_spec(job_dir, scene, config)
    return write_spec_files(job_dir, spec, scene.object_mesh, scene.ice_mesh, defer_povray=defer_povray, start=start)


def build_spec(job_dir: str | Path, scene: JobScene, config: RenderConfig) -> SceneSpec:
    """The `SceneSpec` of a job's scene, arguments as `write_scenes` takes them: the cameras
    framed on ``scene.frame_points``, the ground under them, the sun and sky from the
    config's environment, the ice's look from its ``ice`` and the job's ``impurity``.

    The sky's image is written into ``job_dir`` (created if missing) when it is not there
    yet: the spec names it. Nothing else is written.
    """
    object_mesh, ice_mesh, gravity = scene.object_mesh, scene.ice_mesh, scene.gravity
    ice = ice_at_impurity(config.ice, scene.impurity) if ice_mesh is not None else None
    if scene.ground_level is not None and not np.isfinite(scene.ground_level):
        raise ValueError(f"ground_level must be finite, got {scene.ground_level!r}")
    job_dir = Path(job_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    _check_mesh(object_mesh, "object_mesh")
    if ice_mesh is not None:
        _check_mesh(ice_mesh, "ice_mesh")
    material = material_from_dict(scene.material)
    frame = cam.world_frame(gravity)
    env = config.environment
    sky = _sky_file(job_dir, env)

    # Cameras framed on object + ice, the ground under both.
    points = cam.framing_points(_frame_points(scene))  # the hull's vertices frame the same, much faster
    ground = _ground(points, frame, env.ground, scene.ground_level)
    ground_height = None if ground is None else float(ground.centre @ frame[1])
    cameras = [cam.frame_view(points, gravity, v.azimuth, v.elevation, config.width / config.height,
                              fov_y=config.fov, ground=ground_height)
               for v in config.views]
    cameras, icicle_px = _ice_views(scene, config, frame, cameras, _diagonal(points))

    # Inward winding would make refraction run inside out.
    ice_flip = ice_mesh is not None and geo.winds_inward(ice_mesh.vertices, ice_mesh.faces)
    return SceneSpec(
        resolution=(config.width, config.height),
        views=tuple(SpecView(v.name, v.frame, icicle_px[i]) for i, v in enumerate(config.views)),
        cameras=cameras, frame=frame, gravity=np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity),
        sky=Sky(sky.name, sky_scale(env), env.sky_strength),
        sun=Sun(cam.direction(frame, env.sun_azimuth, env.sun_elevation), sun_irradiance(env), env.sun_strength,
                env.sun_elevation) if env.sun_strength > 0 else None,
        ground=ground, object_file=jd.OBJECT, material=material,
        ice=None if ice is None else replace(ice, shimmer=_shimmer(ice_mesh, ice.shimmer)),
        ice_file=None if ice is None else jd.ICE, ice_flip=bool(ice_flip),
        exposure=env.exposure, sampling=Sampling(config.spp, config.max_depth, config.denoise))


def _frame_points(scene: JobScene) -> np.ndarray:
    """``scene.frame_points``, checked, or by default the object's and the ice's vertices."""
    if scene.frame_points is not None:
        points = np.asarray(scene.frame_points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0 or not np.isfinite(points).all():
            raise ValueError("frame_points must be finite (n, 3) points, n > 0")
        return points
    if scene.ice_mesh is None:
        return np.asarray(scene.object_mesh.vertices)
    return np.vstack([scene.object_mesh.vertices, scene.ice_mesh.vertices])


def _diagonal(points: np.ndarray) -> float:
    """The diagonal of the box of ``points``, meters: the scene's size."""
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def _ground(points: np.ndarray, frame: np.ndarray, pattern: str, level: float | None) -> Ground | None:
    """The ground square under the framed ``points`` (hull vertices, meters) at height ``level``
    along up (None: just below the lowest point), with the environment's ``pattern``; None for
    ``"none"``."""
    if pattern == "none":
        return None
    up = frame[1]
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = _diagonal(points)
    centre = (lo + hi) / 2
    level = (points @ up).min() - 1e-4 * size if level is None else float(level)
    ground_centre = centre + (level - centre @ up) * up
    return square_ground(ground_centre, 15.0 * size, size / 6, frame, pattern,
                         GROUND_CHECKER if pattern == "checker" else (GROUND_PLAIN,))


def _ice_views(scene: JobScene, config: RenderConfig, frame: np.ndarray, cameras: list[cam.Camera],
               size: float) -> tuple[tuple[cam.Camera, ...], list[float | None]]:
    """The views of the ice (the same camera turned and zoomed onto the densest icicles), and
    per view how wide those icicles are in pixels (None where not measured)."""
    ice_mesh, object_mesh = scene.ice_mesh, scene.object_mesh
    icicle_px: list[float | None] = [None] * len(cameras)
    if ice_mesh is None or not any(v.frame == "ice" for v in config.views):
        return tuple(cameras), icicle_px
    focus = ice_focus(ice_mesh.vertices, ice_mesh.faces, surface_points(object_mesh), frame, size,
                      axes=scene.icicle_axes)
    if focus is None:
        return tuple(cameras), icicle_px
    cast = ray_caster(object_mesh)  # what hides icicles from a view
    for i, v in enumerate(config.views):
        if v.frame == "ice":
            cameras[i] = zoom_on_ice(cameras[i], focus, config.width, config.height, cast)
    if focus.diameter:
        # an ice view at the icicles it aims at (its target lies at their depth); others
        # at the middle of all the icicles
        spot = np.median(focus.points, axis=0)
        icicle_px = [round(focus.diameter / pixel_size(c, c.target if v.frame == "ice" else spot, config.width), 2)
                     for c, v in zip(cameras, config.views)]
    return tuple(cameras), icicle_px


def _shimmer(ice_mesh: trimesh.Trimesh, shimmer: float) -> float:
    """``shimmer`` where the ice mesh says where its ripple crests are (`jd.ICE_BANDS`), else 0."""
    bands = ice_mesh.vertex_attributes.get(jd.ICE_BANDS)
    if shimmer <= 0 or bands is None or len(bands) != len(ice_mesh.vertices) or not np.any(bands > 0):
        return 0.0
    return float(shimmer)


def _sky_file(job_dir: Path, env) -> Path:
    """The sky in ``job_dir``: the configured image, or the procedural one; named by what it
    depends on, written when missing."""
    sky = job_dir / jd.sky_name(env.sky, env.sun_azimuth, env.sun_elevation)
    if env.sky == "procedural":
        if not sky.is_file():
            sky.write_bytes(_procedural_sky_exr(env.sun_azimuth, env.sun_elevation))
    else:
        src = Path(env.sky)
        if not sky.is_file() or sky.stat().st_size != src.stat().st_size:
            shutil.copyfile(src, sky)
    return sky


def write_spec_files(job_dir: str | Path, spec: SceneSpec, object_mesh: trimesh.Trimesh,
                     ice_mesh: trimesh.Trimesh | None, *, defer_povray: bool = False,
                     start: float | None = None) -> SceneFiles:
    """Write ``spec`` (`build_spec`) into ``job_dir`` as every format has it: ``object.ply`` (the
    object smooth with its creases kept), ``ice.ply`` when missing, ``scene.xml``
    (`mitsuba.scene_xml`), ``scene.pov`` and its includes (`povray.scene_pov`; now, or
    deferred as in `write_scenes`), ``scene.json`` and ``views.json``.

    The object's normals are computed here once (`geometry.crease_split`) and written with it
    (``object.ply``, ``object.inc``); the ice's too (``SceneFiles.ice_normals``), for
    ``ice.inc`` and the exports. ``ice.ply`` stays as the pipeline wrote it, without normals:
    Mitsuba computes the same angle-weighted ones (to float32 rounding, 1e-4) when it loads
    it, so that ``scene.xml`` renders alike with the ``mitsuba`` command.

    ``start`` (`time.perf_counter`) is when the work began, for ``SceneFiles.seconds``.
    """
    start = time.perf_counter() if start is None else start
    job_dir = Path(job_dir)
    object_geometry = geo.crease_split(object_mesh, CREASE_ANGLE)
    # the ice's normals at its points as ice.ply holds them (float32), which Mitsuba renders and exports read
    ice_normals = None if spec.ice is None else geo.smooth_normals(
        np.asarray(ice_mesh.vertices, dtype=np.float32), ice_mesh.faces)
    pov_file = job_dir / jd.SCENE_POV
    write_pov = functools.partial(
        _write_povray, job_dir, pov_file, object_geometry, ice_mesh, ice_normals, spec.ice_flip,
        pov.scene_pov(spec, object_inc=jd.OBJECT_INC, ice_inc=None if spec.ice is None else jd.ICE_INC))
    if not defer_povray:
        write_pov()
    obj_v, obj_n, obj_f = object_geometry
    object_ply = job_dir / spec.object_file
    geo.write_ply(object_ply, obj_v, obj_f, obj_n)
    ice_ply = None
    if spec.ice is not None:
        ice_ply = job_dir / spec.ice_file
        if not ice_ply.is_file():  # as the pipeline writes it
            write_mesh(ice_ply, ice_mesh)
    xml = job_dir / jd.SCENE_XML
    xml.write_text(mx.scene_xml(spec))
    write_spec(job_dir / jd.SCENE_SPEC, spec)
    jd.write_views(job_dir, [(v.name, v.frame, v.icicle_px) for v in spec.views])
    return SceneFiles(xml=xml, pov=pov_file, object_ply=object_ply, ice_ply=ice_ply, sky=job_dir / spec.sky.file,
                      spec=spec, seconds=time.perf_counter() - start,
                      povray_writer=write_pov if defer_povray else None, ice_normals=ice_normals)


def _write_povray(job_dir: Path, pov_file: Path, object_geometry: tuple[np.ndarray, ...],
                  ice_mesh: trimesh.Trimesh | None, ice_normals: np.ndarray | None, ice_flip: bool,
                  text: str) -> None:
    """``object.inc``, ``ice.inc`` (the ice with ``ice_normals``, flipped with its faces where
    ``ice_flip``) and then ``scene.pov``: its presence means the includes are whole."""
    obj_v, obj_n, obj_f = object_geometry
    pov.write_mesh2(job_dir / jd.OBJECT_INC, "Object_Mesh", obj_v, obj_n, obj_f)
    if ice_mesh is not None:
        normals = ice_normals * (-1.0 if ice_flip else 1.0)
        pov.write_mesh2(job_dir / jd.ICE_INC, "Ice_Mesh", ice_mesh.vertices, normals, ice_mesh.faces, inside=True)
    pov_file.write_text(text)


def read_scene_spec(job_dir: str | Path, material: Material | Mapping | None = None) -> SceneSpec:
    """The `SceneSpec` a job folder's scenes were written from: its ``scene.json``, or for a job
    from before it, what its ``scene.xml`` says (`legacy.spec_from_xml`, with gravity from
    ``params.yaml``, the object's material from ``done.json`` and the views' names from
    ``views.json``).

    Parameters
    ----------
    job_dir : path
    material : Material or mapping, optional
        The object's material, instead of the one the folder records.

    Raises
    ------
    InputError
        Neither file, or one that is not icefarm's, or a bad ``material``.
    """
    job_dir = Path(job_dir)
    if (job_dir / jd.SCENE_SPEC).is_file():
        try:
            spec = read_spec(job_dir / jd.SCENE_SPEC)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{job_dir / jd.SCENE_SPEC}: not a {jd.SCENE_SPEC} written by icefarm ({exc})") from None
        return spec if material is None else replace(spec, material=material_from_dict(material))
    if not (job_dir / jd.SCENE_XML).is_file():
        raise InputError(f"{job_dir} has neither {jd.SCENE_SPEC} nor {jd.SCENE_XML}: its scene was never written")
    job = jd.read_job(job_dir)
    views = jd.read_views(job_dir)
    names = [v["name"] for v in views] if views and all("name" in v for v in views) else None
    gravity = (job.params or {}).get("water.gravity", (0.0, -1.0, 0.0))
    own = material if material is not None else job.stats.get("object_material")
    try:
        return spec_from_xml(job_dir / jd.SCENE_XML, gravity=gravity, material=material_from_dict(own),
                             view_names=names)
    except ValueError as exc:
        raise InputError(str(exc)) from None
