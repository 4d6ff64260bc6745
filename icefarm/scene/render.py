"""Write a job's scenes and render them: Mitsuba in-process, POV-Ray as a command.

The variant (and the libLLVM it needs) is chosen in `icefarm.scene.variants`, the image
files written in `icefarm.scene.images`; both are re-exported here.
"""

from __future__ import annotations

import functools
import json
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from tqdm import tqdm

from ..artifacts import write_mesh
from ..errors import InputError
from . import camera as cam
from . import geometry as geo
from . import mitsuba as mx
from . import povray as pov
from .config import RenderConfig, ice_medium
from .denoise import denoise, denoiser_version
from .focus import ice_focus, pixel_size, surface_points, zoom_on_ice
from .images import _png_to_exr, write_exr, write_png
from .material import Material, material_from_dict
from .sky import procedural_sky
from .spec import SPEC_FILE, scene_spec, write_spec
from .variants import pick_variant

CREASE_ANGLE = 30.0  # degrees: sharper edges of the object stay sharp in shading
PASS_SAMPLES = 1 << 25  # camera samples per Mitsuba render call: bounded memory, visible progress
VIEWS_FILE = "views.json"  # what each view shows and how wide its icicles are, for contact sheets


# ------------------------------------------------------------------------ scenes
@dataclass(frozen=True)
class SceneFiles:
    """What `write_scenes` wrote into a job folder.

    Attributes
    ----------
    xml, pov : Path
        ``scene.xml`` (Mitsuba 3) and ``scene.pov`` (POV-Ray 3.7).
    object_ply, ice_ply : Path
        Meshes the XML names (``ice_ply`` None without ice).
    sky : Path
        Environment image.
    cameras : tuple of Camera
        One per view, the main view first.
    icicle_px : tuple of (float or None)
        Per view, how wide (pixels) the densest icicles are in it; None where not
        measured (no ice view configured, or no icicles).
    ground_height : float or None
        Height of the ground plane along -gravity, meters (None: no ground).
    seconds : float
        Time taken to write everything written before `write_scenes` returned.
    povray_writer : callable or None
        Writes the POV-Ray files, when `write_scenes` was told to defer them: `render_job`
        runs it in a thread once Mitsuba has loaded its scene, with the ice normals
        Mitsuba computed (``ice_normals=``). None once they are written.
    """

    xml: Path
    pov: Path
    object_ply: Path
    ice_ply: Path | None
    sky: Path
    cameras: tuple[cam.Camera, ...]
    seconds: float
    povray_writer: Callable[..., None] | None = None
    icicle_px: tuple[float | None, ...] = ()
    ground_height: float | None = None


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


def write_scenes(job_dir: str | Path, object_mesh: trimesh.Trimesh, ice_mesh: trimesh.Trimesh | None,
                 config: RenderConfig, gravity: Sequence[float] = (0.0, -1.0, 0.0),
                 object_material: Material | Mapping | None = None,
                 frame_points: np.ndarray | None = None,
                 defer_povray: bool = False, impurity: float = 0.0,
                 ground_level: float | None = None) -> SceneFiles:
    """Write ``object.ply``, ``scene.xml``, ``scene.pov`` (+ includes), the sky,
    ``scene.json`` (the scene for every other writer, `icefarm.scene.spec`) and
    ``views.json`` into ``job_dir``.

    ``ice.ply`` is the pipeline's: it is written from ``ice_mesh`` only when missing.

    Parameters
    ----------
    job_dir : path
        The job folder (created if missing).
    object_mesh : trimesh.Trimesh
        The object in meters.
    ice_mesh : trimesh.Trimesh or None
        The ice in meters (watertight); None renders the object alone.
    config : RenderConfig
    gravity : (3,) float
        Gravity direction: "up" is its opposite.
    object_material : Material or mapping, optional
        ``{type, color, roughness, metal}`` (see `material.material_from_dict`); diffuse clay by default.
    frame_points : (n, 3) float, optional
        What the cameras frame and the ground lies under; default the object's and the
        ice's vertices. Pass the same points to every job of a sweep for identical cameras.
    defer_povray : bool
        Leave the POV-Ray files (``scene.pov``, ``object.inc``, ``ice.inc``: tens of
        megabytes of text for million-face ice) to ``SceneFiles.povray_writer``, which
        `render_job` runs alongside Mitsuba's render. Default: written before returning.
    impurity : float
        The job's ``surface.impurity`` in [0, 1]: the ice's scattering (its cloudy core)
        is the config's ``ice.scattering`` times this; 0 gives clear ice.
    ground_level : float, optional
        Height (m, along minus gravity) of the ground plane: the lowest point of an
        object standing on it. Default: just below the lowest framed point.

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
        Empty meshes, a zero gravity, an impurity outside [0, 1] or a ground level that
        is not finite.
    """
    start = time.perf_counter()
    medium = ice_medium(config.ice, impurity) if ice_mesh is not None else None
    if ground_level is not None and not np.isfinite(ground_level):
        raise ValueError(f"ground_level must be finite, got {ground_level!r}")
    job_dir = Path(job_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    _check_mesh(object_mesh, "object_mesh")
    if ice_mesh is not None:
        _check_mesh(ice_mesh, "ice_mesh")
    material = material_from_dict(object_material)
    frame = cam.world_frame(gravity)
    right, up, front = frame

    # Sky: the configured image, or the procedural one; named by what it depends on.
    env = config.environment
    if env.sky == "procedural":
        sky = job_dir / f"sky_az{env.sun_azimuth:g}_el{env.sun_elevation:g}.exr"
        if not sky.is_file():
            sky.write_bytes(_procedural_sky_exr(env.sun_azimuth, env.sun_elevation))
    else:
        src = Path(env.sky)
        sky = job_dir / f"sky_{src.stem}{src.suffix.lower()}"
        if not sky.is_file() or sky.stat().st_size != src.stat().st_size:
            shutil.copyfile(src, sky)

    # Cameras framed on object + ice, the ground under both.
    if frame_points is not None:
        points = np.asarray(frame_points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0 or not np.isfinite(points).all():
            raise ValueError("frame_points must be finite (n, 3) points, n > 0")
    elif ice_mesh is None:
        points = np.asarray(object_mesh.vertices)
    else:
        points = np.vstack([object_mesh.vertices, ice_mesh.vertices])
    points = cam.framing_points(points)  # the hull's vertices frame the same, much faster
    heights = points @ up
    lo, hi = points.min(axis=0), points.max(axis=0)
    size = float(np.linalg.norm(hi - lo))
    centre = (lo + hi) / 2
    ground = None
    if env.ground != "none":
        level = heights.min() - 1e-4 * size if ground_level is None else float(ground_level)
        ground_centre = centre + (level - centre @ up) * up
        ground = mx.Ground(centre=ground_centre, half_size=15.0 * size, cell=size / 6, frame=frame)
    ground_height = None if ground is None else float(ground.centre @ up)
    cameras = [cam.frame_view(points, gravity, v.azimuth, v.elevation, config.width / config.height,
                              fov_y=config.fov, ground=ground_height)
               for v in config.views]
    sun_dir = cam.direction(frame, env.sun_azimuth, env.sun_elevation)

    # Views of the ice: the same camera turned and zoomed onto the densest icicles.
    focus = None
    if ice_mesh is not None and any(v.frame == "ice" for v in config.views):
        focus = ice_focus(ice_mesh.vertices, ice_mesh.faces, surface_points(object_mesh), frame, size)
    icicle_px: list[float | None] = [None] * len(cameras)
    if focus is not None:
        for i, v in enumerate(config.views):
            if v.frame == "ice":
                cameras[i] = zoom_on_ice(cameras[i], focus, config.width, config.height)
        if focus.diameter:
            # an ice view at the icicles it aims at (its target lies at their depth); others
            # at the middle of all the icicles
            spot = np.median(focus.points, axis=0)
            icicle_px = [round(focus.diameter / pixel_size(c, c.target if v.frame == "ice" else spot,
                                                           config.width), 2)
                         for c, v in zip(cameras, config.views)]
    cameras = tuple(cameras)

    # Geometry: the object smooth with its creases kept; the ice as the pipeline wrote it.
    obj_v, obj_n, obj_f = geo.crease_split(object_mesh, CREASE_ANGLE)
    # Inward winding would make refraction run inside out.
    ice_flip = ice_mesh is not None and geo.winds_inward(ice_mesh.vertices, ice_mesh.faces)
    pov_file = job_dir / "scene.pov"
    write_pov = functools.partial(
        _write_povray, job_dir, pov_file, (obj_v, obj_n, obj_f), ice_mesh, ice_flip,
        pov.scene_pov(config, cameras, frame, object_inc="object.inc",
                      ice_inc=None if ice_mesh is None else "ice.inc", sky_file=sky.name,
                      sun_dir=sun_dir, ground=ground, material=material, medium=medium))
    if not defer_povray:
        write_pov()

    object_ply = job_dir / "object.ply"
    geo.write_ply(object_ply, obj_v, obj_f, obj_n)
    ice_ply = None
    if ice_mesh is not None:
        ice_ply = job_dir / "ice.ply"
        if not ice_ply.is_file():  # as the pipeline writes it
            write_mesh(ice_ply, ice_mesh)
    xml = job_dir / "scene.xml"
    xml.write_text(mx.scene_xml(config, cameras, frame, object_ply=object_ply.name,
                                ice_ply=None if ice_ply is None else ice_ply.name, ice_flip=ice_flip,
                                sky_file=sky.name, sun_dir=sun_dir, ground=ground, material=material,
                                medium=medium))
    write_spec(job_dir / SPEC_FILE, scene_spec(
        config, cameras, frame, gravity=gravity, object_ply=object_ply.name,
        ice_ply=None if ice_ply is None else ice_ply.name, ice_flip=ice_flip, sky_file=sky.name, sun_dir=sun_dir,
        ground=ground, material=material, medium=medium))
    (job_dir / VIEWS_FILE).write_text(json.dumps([
        {"index": i, "name": v.name, "frame": v.frame, "stem": view_stem(i), "icicle_px": icicle_px[i]}
        for i, v in enumerate(config.views)], indent=1) + "\n")
    return SceneFiles(xml=xml, pov=pov_file, object_ply=object_ply, ice_ply=ice_ply, sky=sky,
                      cameras=cameras, seconds=time.perf_counter() - start,
                      povray_writer=write_pov if defer_povray else None, icicle_px=tuple(icicle_px),
                      ground_height=ground_height)


def _write_povray(job_dir: Path, pov_file: Path, object_geometry: tuple[np.ndarray, ...],
                  ice_mesh: trimesh.Trimesh | None, ice_flip: bool,
                  text: str, ice_normals: np.ndarray | None = None) -> None:
    """``object.inc``, ``ice.inc`` and then ``scene.pov``: its presence means the includes are whole.

    ``ice_normals`` ``(n, 3)``: the ice's vertex normals as Mitsuba computed them on load,
    so nothing is computed twice; without them, `geometry.smooth_normals` computes the
    same angle-weighted normals.
    """
    obj_v, obj_n, obj_f = object_geometry
    pov.write_mesh2(job_dir / "object.inc", "Object_Mesh", obj_v, obj_n, obj_f)
    if ice_mesh is not None:
        if ice_normals is None or len(ice_normals) != len(ice_mesh.vertices):
            ice_normals = geo.smooth_normals(ice_mesh.vertices, ice_mesh.faces)
        normals = ice_normals * (-1.0 if ice_flip else 1.0)
        pov.write_mesh2(job_dir / "ice.inc", "Ice_Mesh", ice_mesh.vertices, normals, ice_mesh.faces, inside=True)
    pov_file.write_text(text)


def _vertex_normals(scene, shape_id: str) -> np.ndarray | None:
    """Vertex normals ``(n, 3)`` of the mesh ``shape_id`` in a loaded Mitsuba scene, or None."""
    import mitsuba as mi

    for shape in scene.shapes():
        if shape.id() == shape_id:
            params = mi.traverse(shape)
            if "vertex_normals" in params:
                normals = np.array(params["vertex_normals"], dtype=np.float64)
                if normals.size:
                    return normals.reshape(-1, 3)
    return None


# ------------------------------------------------------------------------ rendering
@dataclass(frozen=True)
class RenderResult:
    """Timings and files of one job's render.

    Attributes
    ----------
    renderer : str
        ``mitsuba``, ``povray`` or ``both``.
    variant : str
        Mitsuba variant used (``""`` when Mitsuba did not run).
    integrator : str
        Mitsuba integrator: ``icepath`` (scenes with ice on JIT variants), else the XML's
        ``path`` or ``volpath``.
    seconds : float
        Mitsuba render time, all views, up to the NumPy conversion of the image.
    write_seconds : float
        Writing the scenes before the render (when `SceneFiles` were given).
    load_seconds : float
        Loading scene.xml (meshes, BVH).
    wait_seconds : float
        Waiting after the render for POV-Ray files written in the background.
    povray_write_cpu_seconds : float
        CPU time of that background writer (0 when nothing was deferred): on a machine
        whose cores the render keeps busy, it slows the render by about as much.
    povray_seconds : float
        POV-Ray wall time, all views (0 when it did not run).
    files : tuple of Path
        Images written, the main ``render.exr`` and ``render.png`` first.
    view_seconds : tuple of float
        Mitsuba's time per view (they add up to ``seconds``).
    denoise_seconds : float
        Of ``seconds``, the denoiser's (0 when the config does not denoise).
    """

    renderer: str
    variant: str
    integrator: str
    seconds: float
    write_seconds: float
    load_seconds: float
    wait_seconds: float
    povray_write_cpu_seconds: float
    povray_seconds: float
    files: tuple[Path, ...]
    view_seconds: tuple[float, ...] = ()
    denoise_seconds: float = 0.0

    @property
    def scene_seconds(self) -> float:
        """What the job spends on its scenes beyond rendering: writing, loading, waiting."""
        return self.write_seconds + self.load_seconds + self.wait_seconds


def view_stem(index: int, prefix: str = "render") -> str:
    """File stem of view ``index``: ``render`` for the main view, ``render_view<i>`` after."""
    return prefix if index == 0 else f"{prefix}_view{index}"


def sample_passes(pixels: int, spp: int, budget: int = PASS_SAMPLES) -> list[int]:
    """Split ``spp`` samples per pixel into passes of at most about ``budget`` samples each.

    Returns the samples per pixel of each pass (they sum to ``spp``): one pass for
    preview and lookdev frames, several for final frames.
    """
    if pixels < 1 or spp < 1 or budget < 1:
        raise ValueError(f"pixels, spp and budget must be >= 1, got {pixels}, {spp}, {budget}")
    count = min(spp, -(-pixels * spp // budget))
    base, extra = divmod(spp, count)
    return [base + (k < extra) for k in range(count)]


def render_mitsuba(job_dir: Path, config: RenderConfig, variant: str,
                   on_loaded: Callable[[object], None] | None = None,
                   progress: bool = False) -> tuple[float, float, list[Path], str]:
    """Load ``scene.xml`` with ``variant`` and render every view; ``on_loaded(scene)`` runs in between.

    Scenes with ice render with the ice-aware path tracer (`integrator.ice_integrator`:
    sunlight reaches what the glaze covers; the ice's medium as the XML gives it) on JIT
    variants, with the XML's ``path`` or ``volpath`` otherwise. Large frames render in
    passes (`sample_passes`, each with its own seed, averaged), with a progress bar over
    them when ``progress`` is set.

    With ``config.denoise`` set, each view is denoised (`denoise.denoise`) with the
    albedo and normal icepath writes beside it.

    Returns
    -------
    MitsubaRun
    """
    import mitsuba as mi

    from .integrator import FEATURE_CHANNELS, ice_integrator, medium_coefficients

    if mi.variant() != variant:
        mi.set_variant(variant)
    start = time.perf_counter()
    scene = mi.load_file(str(job_dir / "scene.xml"))
    load_seconds = time.perf_counter() - start
    if on_loaded is not None:
        on_loaded(scene)
    has_ice = any(shape.id() == "ice" for shape in scene.shapes())
    denoised = config.denoise == "oidn"
    integrator = None
    if (has_ice or denoised) and variant.startswith(("llvm_", "cuda_")):
        # the medium as scene.xml has it (written from the config and the job's impurity);
        # without ice icepath is a plain path tracer, that also writes the denoiser's features
        sigma_a, sigma_s = medium_coefficients(scene, "ice") or ((0.0,) * 3, (0.0,) * 3)
        integrator = ice_integrator(variant, config.max_depth, config.ice.ior, config.ice.tint,
                                    sigma_a=sigma_a, sigma_s=sigma_s, features=denoised)
    channels = 3 + (len(FEATURE_CHANNELS) if denoised and integrator is not None else 0)
    passes = sample_passes(config.width * config.height, config.spp, PASS_SAMPLES)
    n_views = len(scene.sensors())
    bar = tqdm(total=n_views * config.spp, unit="spp", desc="render", dynamic_ncols=True,
               disable=not progress or len(passes) == 1 and n_views == 1)
    view_seconds, denoise_seconds, files = [], 0.0, []
    for i in range(n_views):
        start = time.perf_counter()
        image = np.zeros((config.height, config.width, channels))
        for seed, spp in enumerate(passes):
            rendered = np.asarray(mi.render(scene, sensor=i, spp=spp, seed=seed, integrator=integrator))
            image += _channels(rendered, channels) * (spp / config.spp)
            bar.update(spp)
        rgb = image[..., :3]
        if denoised:
            rendered_at = time.perf_counter()
            rgb = denoise(rgb, *((image[..., 3:6], image[..., 6:9]) if channels > 3 else ()))
            denoise_seconds += time.perf_counter() - rendered_at
        view_seconds.append(time.perf_counter() - start)
        stem = view_stem(i)
        write_exr(job_dir / f"{stem}.exr", rgb, attributes=_denoise_note(config, channels) if denoised else None)
        write_png(job_dir / f"{stem}.png", rgb)
        files += [job_dir / f"{stem}.exr", job_dir / f"{stem}.png"]
    bar.close()
    name = "icepath" if integrator is not None else _integrator_name(scene)
    del scene  # no scene outlives the job (Mitsuba's memory grows with loads)
    return MitsubaRun(load_seconds, tuple(view_seconds), denoise_seconds, tuple(files), name)


@dataclass(frozen=True)
class MitsubaRun:
    """What `render_mitsuba` did.

    Attributes
    ----------
    load_seconds : float
        Loading ``scene.xml``.
    view_seconds : tuple of float
        Per view: rendering, denoising and converting the image (writing it excluded).
    denoise_seconds : float
        Denoising, all views (0 when the config does not denoise).
    files : tuple of Path
        The images written.
    integrator : str
        ``icepath``, or what scene.xml names (``path``, ``volpath`` when the ice holds a
        medium) where icepath does not run (scalar variants, scenes without ice that
        are not denoised).
    """

    load_seconds: float
    view_seconds: tuple[float, ...]
    denoise_seconds: float
    files: tuple[Path, ...]
    integrator: str


def _channels(rendered: np.ndarray, channels: int) -> np.ndarray:
    """RGB (and the features after it) of ``mi.render``'s image, which may hold alpha
    and a weight before the features."""
    if channels == 3 or rendered.shape[-1] == channels:
        return rendered[..., :channels]
    return np.concatenate([rendered[..., :3], rendered[..., -(channels - 3):]], axis=-1)


def _denoise_note(config: RenderConfig, channels: int) -> dict[str, str]:
    """The EXR attribute that says what was denoised, with what and from how many samples."""
    guides = "albedo and normal features" if channels > 3 else "colour only"
    return {"icefarm:denoised": f"{denoiser_version()} RT filter, HDR, {guides}, from {config.spp} spp; "
                                "pixels stay linear"}


def _integrator_name(scene) -> str:
    """``path`` or ``volpath``: the plugin scene.xml names (from the integrator's description)."""
    text = str(scene.integrator())
    return "volpath" if text.startswith("Volumetric") else "path"


def _cpu_seconds(task: Callable[[], None]) -> float:
    """Run ``task`` and return the CPU time this thread spent on it."""
    start = time.thread_time()
    task()
    return time.thread_time() - start


def render_job(job_dir: str | Path, config: RenderConfig, scene: SceneFiles | None = None,
               progress: bool = False) -> RenderResult:
    """Render the scenes `write_scenes` put in ``job_dir`` with the config's renderer(s).

    Mitsuba writes ``render.exr`` (linear) and ``render.png`` (sRGB), plus
    ``render_view<i>.*`` for further views; POV-Ray writes ``render_povray.png`` (and,
    when it is the only renderer, ``render.png``/``render.exr`` from it).

    Parameters
    ----------
    job_dir : path
    config : RenderConfig
    scene : SceneFiles, optional
        What `write_scenes` returned: its write time counts in ``scene_seconds``. POV-Ray
        files it deferred are written in a thread while Mitsuba renders (after its load,
        which is parallel already); waiting for them after the render counts too.
    progress : bool
        A progress bar over the samples of long renders (several passes or views).

    Raises
    ------
    InputError
        POV-Ray asked for but not installed, or a variant that cannot run here.
    """
    job_dir = Path(job_dir)
    writer = scene.povray_writer if scene is not None else None
    pending: list[Future] = []
    with ThreadPoolExecutor(max_workers=1) as pool:
        def start_povray(mitsuba_scene=None) -> None:
            if writer is not None and not pending:
                normals = None if mitsuba_scene is None else _vertex_normals(mitsuba_scene, "ice")
                pending.append(pool.submit(_cpu_seconds, functools.partial(writer, ice_normals=normals)))

        try:
            if config.uses_mitsuba and not (job_dir / "scene.xml").is_file():
                raise InputError(f"no scene.xml in {job_dir}: write the scenes first")
            if config.uses_povray:
                pov.require_povray()  # before spending time on Mitsuba
            files: list[Path] = []
            variant, integrator, load_seconds, pov_seconds = "", "", 0.0, 0.0
            views, denoise_seconds = (), 0.0
            if config.uses_mitsuba:
                variant = pick_variant(config.variant)
                run = render_mitsuba(job_dir, config, variant, on_loaded=start_povray if writer else None,
                                     progress=progress)
                load_seconds, views, denoise_seconds = run.load_seconds, run.view_seconds, run.denoise_seconds
                files, integrator = list(run.files), run.integrator
        finally:  # the job is not over while its scene.pov is missing or being written
            start = time.perf_counter()
            start_povray()
            writer_cpu = pending[0].result() if pending else 0.0
            waited = time.perf_counter() - start
    if config.uses_povray:
        n_views = len(config.views)
        for i in range(n_views):
            out = f"{view_stem(i, 'render_povray')}.png"
            pov_seconds += pov.render_povray(job_dir, config, view=i, output=out)
            files.append(job_dir / out)
            if not config.uses_mitsuba:
                stem = view_stem(i)
                shutil.copyfile(job_dir / out, job_dir / f"{stem}.png")
                _png_to_exr(job_dir / out, job_dir / f"{stem}.exr")
                files += [job_dir / f"{stem}.exr", job_dir / f"{stem}.png"]
    if not config.uses_mitsuba:  # keep render.exr, render.png first
        files.sort(key=lambda p: (not p.name.startswith("render."), p.name))
    return RenderResult(renderer=config.renderer, variant=variant, integrator=integrator, seconds=sum(views),
                        view_seconds=views, denoise_seconds=denoise_seconds,
                        write_seconds=scene.seconds if scene is not None else 0.0,
                        load_seconds=load_seconds, wait_seconds=waited, povray_write_cpu_seconds=writer_cpu,
                        povray_seconds=pov_seconds, files=tuple(files))
