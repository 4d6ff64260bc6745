"""Render the scenes a job's folder holds (`icefarm.scene.write`): Mitsuba in-process, POV-Ray as
a command.

The variant (and the libLLVM it needs) is chosen in `icefarm.scene.variants`, the image
files written in `icefarm.scene.images`.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..errors import InputError
from ..jobdir import POVRAY_STEM, SCENE_SPEC, SCENE_XML, view_stem
from . import povray as pov
from .config import RenderConfig
from .denoise import denoise, denoiser_version
from .images import png_to_exr, write_exr, write_png
from .spec import SceneSpec, read_spec
from .variants import pick_variant
from .write import JobScene, SceneFiles, write_scenes

# write_scenes and SceneFiles live in icefarm.scene.write; callers that write and render meet them here too
__all__ = ["JobScene", "MitsubaRun", "RenderResult", "SceneFiles", "render_job", "render_mitsuba", "sample_passes",
           "write_scenes"]

PASS_SAMPLES = 1 << 25  # camera samples per Mitsuba render call: bounded memory, visible progress
REPORT_S = 10.0  # a render's progress lines in a log: at most one per this many seconds, and one per view


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
        Waiting after the render for what was written in the background (the POV-Ray files;
        in a job, the USD export after them).
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
    scene : SceneFiles or None
        What was written and rendered, when `render_job` was given them or wrote them.
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
    scene: SceneFiles | None = None

    @property
    def scene_seconds(self) -> float:
        """What the job spends on its scenes beyond rendering: writing, loading, waiting."""
        return self.write_seconds + self.load_seconds + self.wait_seconds


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


def render_mitsuba(job_dir: Path, config: RenderConfig, variant: str, spec: SceneSpec,
                   on_loaded: Callable[[object], None] | None = None,
                   progress: bool = False, report: Callable[[str], None] | None = None) -> MitsubaRun:
    """Load ``scene.xml`` with ``variant`` and render every view; ``on_loaded(scene)`` runs in between.

    Scenes with ice render with the ice-aware path tracer (`integrator.ice_integrator`:
    sunlight reaches what the glaze covers; the ice's look and medium as ``spec``, the scene
    ``scene.xml`` was written from, gives them) on JIT variants, with the XML's ``path`` or
    ``volpath`` otherwise. Large frames render in
    passes (`sample_passes`, each with its own seed, averaged), with a progress bar over
    them when ``progress`` is set. ``report(line)``, for a log or a pipe, is told as each view
    ends and at most every `REPORT_S` seconds in between: how far the samples are, and the
    time left at that pace.

    With ``config.denoise`` set, each view is denoised (`denoise.denoise`) with the
    albedo and normal icepath writes beside it.

    Returns
    -------
    MitsubaRun
    """
    import mitsuba as mi

    from .config import ice_medium
    from .integrator import FEATURE_CHANNELS, ice_integrator

    if mi.variant() != variant:
        mi.set_variant(variant)
    start = time.perf_counter()
    scene = mi.load_file(str(job_dir / SCENE_XML))
    load_seconds = time.perf_counter() - start
    if on_loaded is not None:
        on_loaded(scene)
    denoised = config.denoise == "oidn"
    integrator = None
    if (spec.ice is not None or denoised) and variant.startswith(("llvm_", "cuda_")):
        # without ice icepath is a plain path tracer, that also writes the denoiser's features
        medium = ice_medium(spec.ice) if spec.ice is not None else None
        integrator = ice_integrator(variant, config.max_depth, ice=spec.ice, medium=medium, features=denoised)
    channels = 3 + (len(FEATURE_CHANNELS) if denoised and integrator is not None else 0)
    passes = sample_passes(config.width * config.height, config.spp, PASS_SAMPLES)
    n_views = len(scene.sensors())
    bar = tqdm(total=n_views * config.spp, unit="spp", desc="render", dynamic_ncols=True,
               disable=not progress or len(passes) == 1 and n_views == 1)
    view_seconds, denoise_seconds, files = [], 0.0, []
    began = reported = time.perf_counter()
    total, done = n_views * config.spp, 0

    def tell(now: float, what: str) -> None:
        left = (now - began) * (total - done) / max(done, 1)
        report(f"{what}: {100 * done / total:.0f} % of {total} samples per pixel in {now - began:.0f} s"
               + (f", about {left:.0f} s left" if done < total else ""))

    for i in range(n_views):
        start = time.perf_counter()
        image = np.zeros((config.height, config.width, channels))
        for seed, spp in enumerate(passes):
            rendered = np.asarray(mi.render(scene, sensor=i, spp=spp, seed=seed, integrator=integrator))
            image += _channels(rendered, channels) * (spp / config.spp)
            bar.update(spp)
            done += spp
            if report is not None and (now := time.perf_counter()) - reported >= REPORT_S and done < total:
                tell(now, f"view {i + 1} of {n_views}")
                reported = now
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
        if report is not None:
            tell(time.perf_counter(), f"view {i + 1} of {n_views} done ({stem}.png)")
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


def render_job(job_dir: str | Path, config: RenderConfig, scene: JobScene | SceneFiles | None = None,
               progress: bool = False, povray_files: bool = True,
               report: Callable[[str], None] | None = None) -> RenderResult:
    """Render a job's scene in ``job_dir`` with the config's renderer(s): the one way a job's
    scene is rendered (the pipeline, ``icefarm render``, growth frames and the benchmarks).

    Given a `JobScene`, the scene is written first (`write_scenes`: the spec, then
    ``scene.xml``, ``scene.json``, the meshes; the POV-Ray files while Mitsuba renders).
    Given `SceneFiles`, what `write_scenes` wrote is rendered; given nothing, what
    ``job_dir`` holds (its ``scene.json`` says what ``scene.xml`` holds).

    Mitsuba writes ``render.exr`` (linear) and ``render.png`` (sRGB), plus
    ``render_view<i>.*`` for further views; POV-Ray writes ``render_povray.png`` (and,
    when it is the only renderer, ``render.png``/``render.exr`` from it).

    Parameters
    ----------
    job_dir : path
    config : RenderConfig
    scene : JobScene or SceneFiles, optional
        What the scene is made of, or what `write_scenes` returned: the write time counts
        in ``scene_seconds``. POV-Ray files it deferred are written in a thread while
        Mitsuba renders (after its load, which is parallel already); waiting for them
        after the render counts too.
    progress : bool
        A progress bar over the samples of long renders (several passes or views).
    report : callable, optional
        ``report(line)``: progress lines for a log (`render_mitsuba`).
    povray_files : bool
        Write the POV-Ray files of a `JobScene` even when the config renders with Mitsuba
        alone (False: only when POV-Ray renders).

    Raises
    ------
    InputError
        POV-Ray asked for but not installed, a variant that cannot run here, or for
        Mitsuba, no scenes written (``scene.xml``, ``scene.json``).
    """
    job_dir = Path(job_dir)
    if isinstance(scene, JobScene):
        scene = write_scenes(job_dir, scene, config, defer_povray=True)
        if not (povray_files or config.uses_povray):
            scene = dataclasses.replace(scene, povray_writer=None)
    writer = scene.povray_writer if scene is not None else None
    pending: list[Future] = []
    with ThreadPoolExecutor(max_workers=1) as pool:

        def start_povray() -> None:
            if writer is not None and not pending:
                pending.append(pool.submit(_cpu_seconds, writer))

        try:
            missing = next((name for name in (SCENE_XML, SCENE_SPEC) if not (job_dir / name).is_file()), None)
            if config.uses_mitsuba and missing is not None:
                raise InputError(f"no {missing} in {job_dir}: write the scenes first")
            if config.uses_povray:
                pov.require_povray()  # before spending time on Mitsuba
            files: list[Path] = []
            variant, integrator, load_seconds, pov_seconds = "", "", 0.0, 0.0
            views, denoise_seconds = (), 0.0
            if config.uses_mitsuba:
                variant = pick_variant(config.variant)
                spec = scene.spec if scene is not None else read_spec(job_dir / SCENE_SPEC)
                run = render_mitsuba(job_dir, config, variant, spec, on_loaded=lambda _loaded: start_povray(),
                                     progress=progress, report=report)
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
            out = f"{view_stem(i, POVRAY_STEM)}.png"
            pov_seconds += pov.render_povray(job_dir, config, view=i, output=out)
            files.append(job_dir / out)
            if not config.uses_mitsuba:
                stem = view_stem(i)
                shutil.copyfile(job_dir / out, job_dir / f"{stem}.png")
                png_to_exr(job_dir / out, job_dir / f"{stem}.exr")
                files += [job_dir / f"{stem}.exr", job_dir / f"{stem}.png"]
    if not config.uses_mitsuba:  # keep render.exr, render.png first
        files.sort(key=lambda p: (not p.name.startswith("render."), p.name))
    return RenderResult(renderer=config.renderer, variant=variant, integrator=integrator, seconds=sum(views),
                        view_seconds=views, denoise_seconds=denoise_seconds,
                        write_seconds=scene.seconds if scene is not None else 0.0,
                        load_seconds=load_seconds, wait_seconds=waited, povray_write_cpu_seconds=writer_cpu,
                        povray_seconds=pov_seconds, files=tuple(files), scene=scene)
