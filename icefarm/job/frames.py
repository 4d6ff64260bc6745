"""Growth over time, its run and files: a job's ice at N moments from the first drip to full
growth, each frame's stage 4 on the inputs `icefarm.stages.growth` scales to its fraction
``f`` of the growth, rendered with the job's camera, written as ``growth/`` (frames, MP4,
time-sampled USD).

Stages 1-3 run once, at full growth. Every size grows with ``f`` and the bases and glaze draw
what the full job draws (`icefarm.stages.growth.noise_draws`), so the ice of a frame lies
inside the next one's and frame N is the job's own ``ice.ply``, bit for bit. Inside up to
``surface.noise``: the icicles' balls are re-spaced each frame and draw their noise anew
(measured: 0.43 mm out at the default 0.4 mm noise, 0.02 mm with none, on a 0.6 m roof at
1.5 mm voxels).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .. import artifacts
from ..export.growth_usd import write_growth_usd
from ..geometry import arc_lengths
from ..jobdir import (
    FRAMES,
    GROWTH_MP4,
    GROWTH_SCRATCH,
    GROWTH_USDA,
    ICE,
    ICE_BANDS,
    RENDER_PNG,
    growth_frame,
    growth_ice,
)
from ..params import GlazeParams, SurfaceParams
from ..scene.write import JobScene
from ..stages.drips import DripResult
from ..stages.growth import frame_fractions, noise_draws, stage4_inputs_at, trajectories_at
from ..stages.trajectories import TrajectoryResult

# The movie lasts about this long, at 1 to 24 frames per second.
MOVIE_SECONDS = 3.0


@dataclass(frozen=True)
class FrameView:
    """How every frame is rendered: the job's scene, one camera for all frames.

    Attributes
    ----------
    scene : icefarm.scene.write.JobScene
        The job's scene with the fully grown ice (`icefarm.scene.write.job_scene`): its
        cameras frame the object and all the ice, so nothing jumps; each frame puts its
        own ice in it.
    config : icefarm.scene.config.RenderConfig
        The job's render config; frames use its main view only, framed on the whole scene.
    """

    scene: JobScene
    config: object


@dataclass(frozen=True)
class GrowthFrame:
    """One frame's ice and its plausibility figures (a row of ``frames.json``).

    Lengths in meters, radii in millimeters; medians over the trunks measured (None where
    none could be: trunks shorter than about 7 mm). ``length_per_width``: per trunk, the
    length it gained since the frame before (the first frame: since the drop) over the
    diameter it gained 10 % of its length below its base (real icicles: 8-32).
    """

    index: int
    fraction: float
    ice_faces: int
    volume_m3: float
    trunk_length_m: float | None
    tip_radius_mm: float | None
    taper: float | None
    growth_ratio: float | None
    length_per_width: float | None
    surface_seconds: float
    render_seconds: float


@dataclass(frozen=True)
class GrowthResult:
    """What `grow_frames` wrote into ``folder``: ``ice_####.ply``, ``frame_####.png`` (with a
    view), ``growth.mp4`` (with a view), ``growth.usda`` (value clips ``ice_0001.usdc``...,
    `icefarm.export.growth_usd`), ``frames.json``."""

    folder: Path
    frames: tuple[GrowthFrame, ...]
    movie: Path | None
    usd: Path

    @property
    def seconds_per_frame(self) -> float:
        """Median seconds of a frame's stage 4 and render."""
        return float(np.median([f.surface_seconds + f.render_seconds for f in self.frames]))


@dataclass(frozen=True)
class Growing:
    """What a job's growth frames grow from.

    Attributes
    ----------
    traj, drips : TrajectoryResult, DripResult
        The job's stages 2-3 at full growth.
    surface, glaze : SurfaceParams, GlazeParams
        The resolved ``surface`` and ``glaze`` groups.
    gravity : (3,) float
    frames : int
        In [1, `MAX_FRAMES`].
    object_usd : path, optional
        The job's ``object.usdc``, referenced by ``growth.usda`` when it exists.
    scene_usd : path, optional
        The job's ``scene.usda``: ``growth.usda`` takes its materials, ground, cameras and
        lights when it exists.
    """

    traj: TrajectoryResult
    drips: DripResult
    surface: SurfaceParams
    glaze: GlazeParams
    gravity: np.ndarray
    frames: int
    object_usd: str | Path | None = None
    scene_usd: str | Path | None = None


def grow_frames(folder: str | Path, growing: Growing, *, build: Callable,
                new_rng: Callable[[], np.random.Generator], view: FrameView | None = None,
                progress: bool = False) -> GrowthResult:
    """Stage 4 (and a render) at each of ``growing.frames`` fractions of the growth, into ``folder``.

    Parameters
    ----------
    folder : path
        Emptied first: ``ice_0001.ply`` ... (meters), ``frame_0001.png`` ... and
        ``growth.mp4`` with a ``view``, ``growth.usda``, ``frames.json``.
    growing : Growing
    build : callable
        ``build(traj, drips, glaze, rng) -> IceResult``: stage 4 exactly as the job runs it.
    new_rng : callable
        A fresh generator of the job's stage 4 stream (PCG64, `numpy.random.default_rng`).
    view : FrameView, optional
        Render each frame (and the movie); None: meshes and figures only.
    progress : bool
        A progress bar over the frames.
    """
    from tqdm import tqdm

    from ..stages.surface import measure_icicles

    traj, drips, surface, glaze, frames = growing.traj, growing.drips, growing.surface, growing.glaze, growing.frames
    folder = Path(folder)
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    full_draws = noise_draws(traj, surface)
    rows, plies, pngs = [], [], []
    trunks = (np.asarray(traj.branch_parent) < 0) & (np.diff(traj.branch_offsets) > 0)  # as measure_icicles's
    was_long, was_wide = 0.0, 2 * surface.tip_radius  # before the first frame: the drop
    for i, f in enumerate(tqdm(frame_fractions(frames), desc="growth", unit="frame", disable=not progress), 1):
        start = time.perf_counter()
        traj_f = trajectories_at(traj, f)
        drips_f, glaze_f = stage4_inputs_at(drips, glaze, f)
        rng = new_rng()
        # modulo the period: a frame with more balls than the full growth steps back
        rng.bit_generator.advance((full_draws - noise_draws(traj_f, surface)) % 2**128)
        ice = build(traj_f, drips_f, glaze_f, rng)
        axes = ice.axes if ice.axes is not None else traj_f
        mesh = trimesh.Trimesh(ice.vertices, ice.faces, process=False)
        if ice.bands is not None:  # milky under the crests, as the job's ice.ply
            mesh.vertex_attributes[ICE_BANDS] = ice.bands
        plies.append(folder / growth_ice(i))
        artifacts.write_mesh(plies[-1], mesh)  # as the job writes ice.ply: the last frame is that file
        surface_seconds = time.perf_counter() - start
        render_seconds = 0.0
        if view is not None:
            start = time.perf_counter()
            pngs.append(render_frame(view, mesh, folder / GROWTH_SCRATCH, folder / growth_frame(i)))
            render_seconds = time.perf_counter() - start
        m = measure_icicles(ice.vertices, ice.faces, axes, surface)
        long = arc_lengths(traj_f.points, np.asarray(traj_f.branch_offsets))[1][trunks]
        wide = 2 * m.taper * surface.tip_radius
        gained = np.divide(long - was_long, wide - was_wide, out=np.full(len(long), np.nan),
                           where=wide - was_wide > 0)
        measured = np.isfinite(wide)  # a trunk too short to measure is compared later, with more growth
        was_long, was_wide = np.where(measured, long, was_long), np.where(measured, wide, was_wide)
        rows.append(GrowthFrame(
            index=i, fraction=round(float(f), 6), ice_faces=len(ice.faces),
            volume_m3=float(abs(mesh.volume)) if len(ice.faces) else 0.0,
            trunk_length_m=_median(long), tip_radius_mm=_median([m.tip_radius_mm]),
            taper=_median(m.taper), growth_ratio=_median(m.growth_ratio), length_per_width=_median(gained),
            surface_seconds=round(surface_seconds, 4), render_seconds=round(render_seconds, 4)))
    shutil.rmtree(folder / GROWTH_SCRATCH, ignore_errors=True)
    fps = float(np.clip(frames / MOVIE_SECONDS, 1.0, 24.0))
    movie = write_movie(pngs, folder / GROWTH_MP4, fps) if pngs else None
    usd = write_growth_usd(folder / GROWTH_USDA, plies, growing.gravity, fps, growing.object_usd, growing.scene_usd)
    artifacts.write_json(folder / FRAMES, {"fps": fps, "frames": [dataclasses.asdict(r) for r in rows]})
    return GrowthResult(folder, tuple(rows), movie, usd)


def render_frame(view: FrameView, ice: trimesh.Trimesh, scratch: Path, png: Path) -> Path:
    """Render ``ice`` with ``view`` in ``scratch`` (rewritten each frame) and move its image to ``png``.

    Only the main view renders, framed on the whole scene (an ``ice`` view zooms on the
    densest icicles of each frame: its camera would move), with Mitsuba when the config
    uses it (POV-Ray otherwise), at the config's resolution and samples.
    """
    from ..scene.render import render_job

    config = view.config
    main = dataclasses.replace(config.views[0], frame="all")
    config = dataclasses.replace(config, views=(main,), renderer="mitsuba" if config.uses_mitsuba else "povray")
    scratch.mkdir(parents=True, exist_ok=True)
    (scratch / ICE).unlink(missing_ok=True)  # write_scenes keeps an ice.ply it finds
    scene = dataclasses.replace(view.scene, ice_mesh=ice if len(ice.faces) else None)
    render_job(scratch, config, scene, povray_files=False)  # no scene.pov per frame unless POV-Ray renders it
    shutil.move(scratch / RENDER_PNG, png)
    return png


def write_movie(pngs: Sequence[Path], path: Path, fps: float) -> Path:
    """An H.264 MP4 of ``pngs`` (one frame each, same size) through imageio-ffmpeg's own ffmpeg."""
    import imageio_ffmpeg
    import OpenImageIO as oiio

    def rgb(png: Path) -> np.ndarray:
        pixels = np.asarray(oiio.ImageBuf(str(png)).get_pixels(oiio.UINT8))
        pixels = np.repeat(pixels, 3, axis=2) if pixels.shape[2] == 1 else pixels[..., :3]
        # yuv420p needs even sides: repeat the last row or column
        return np.pad(pixels, ((0, pixels.shape[0] % 2), (0, pixels.shape[1] % 2), (0, 0)), mode="edge")

    first = rgb(pngs[0])
    tmp = path.with_name(f".{path.name}")
    writer = imageio_ffmpeg.write_frames(str(tmp), (first.shape[1], first.shape[0]), fps=fps, codec="libx264",
                                         macro_block_size=1, ffmpeg_log_level="error",
                                         output_params=["-movflags", "+faststart"])
    writer.send(None)  # start ffmpeg
    try:
        writer.send(np.ascontiguousarray(first))
        for png in pngs[1:]:
            writer.send(np.ascontiguousarray(rgb(png)))
    finally:
        writer.close()
    tmp.replace(path)
    return path


def read_frames(folder: str | Path) -> list[dict]:
    """The rows of a growth folder's ``frames.json``."""
    return json.loads((Path(folder) / FRAMES).read_text())["frames"]


def _median(values) -> float | None:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return round(float(np.median(values)), 6) if len(values) else None
