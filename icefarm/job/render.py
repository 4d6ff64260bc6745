"""A job's render step: its object and ice as a scene, rendered with its render config, and
the USD scene for DCCs, written while Mitsuba renders.

`icefarm.job.pipeline.run_job` runs it after the surface stage; on a farm whose renders go to
GPU workers, `icefarm.job.pipeline.finish_render` runs it on its own from the job's files.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from ..placement import ground_height

Timed = Callable[..., Any]  # timed(step, work, own_bars=False): runs and times one step


def return_freed_memory() -> None:
    """Hand the heap's freed pages back to the system before the render loads its scene.

    The surface stage frees hundreds of MB of temporaries that glibc keeps mapped; Mitsuba's
    scene and BVH then come on top of them: without this the 3 m house's preview peaks at
    1.62-1.96 GB resident in the render (5 runs), against 1.53-1.54 GB with it (3 runs), its peak
    then the surface stage's. glibc only (``malloc_trim``); elsewhere nothing happens."""
    import ctypes

    try:
        trim = getattr(ctypes.CDLL(None), "malloc_trim", None)
    except (OSError, TypeError):  # no handle on the process's own symbols (Windows)
        return
    if trim is not None:
        trim(0)


def render_step(spec, job_dir: Path, obj: trimesh.Trimesh, ice_mesh: trimesh.Trimesh | None,
                icicle_axes: np.ndarray | None, timed: Timed, progress: bool) -> dict:
    """Render ``spec``'s job (an `icefarm.job.pipeline.JobSpec` with a render config) into
    ``job_dir`` and write its USD scene; the figures of the render for ``timings.json``.

    Parameters
    ----------
    obj : trimesh.Trimesh
        The prepared object, in meters, placed.
    ice_mesh : trimesh.Trimesh or None
        The ice (``ice.ply``, with its ripple bands where it has them); None: no ice.
    icicle_axes : (p, 3) float or None
        The trajectories' points, which frame the ice view.
    timed : callable
        ``timed(step, work, own_bars=False)``: the job's timer (the steps ``render`` and ``usd``).
    progress : bool
        Bars over the render's samples.
    """
    from ..export.usd import read_usd_inputs, write_usd
    from ..scene.config import load_render_config
    from ..scene.render import render_job
    from ..scene.write import job_scene, write_scenes

    gravity = spec.params.gravity

    config = load_render_config(spec.render)
    scene = job_scene(obj, ice_mesh, gravity, material=spec.material, placement=spec.placement,
                      impurity=spec.params.surface.impurity,  # impure water: a cloudy core
                      # framed on trajectories.json's axes, as `icefarm render` frames it again
                      # (stage 4's, with roots hung under the rims, would move the ice view)
                      icicle_axes=icicle_axes)
    material = scene.material
    exported: list[tuple[Future, dict]] = []

    def render():
        files = write_scenes(job_dir, scene, config, defer_povray=True)
        # The USD export needs the written scene, not its images: it is read here and written
        # after the POV-Ray files in the thread `render_job` writes them in while Mitsuba renders
        # (the reading parses, which must not happen in two threads at once: `read_usd_inputs`).
        future, export, took = _beside(functools.partial(read_usd_inputs, job_dir, material=material,
                                                         ice_mesh=ice_mesh),
                                       functools.partial(write_usd, ice_normals=files.ice_normals))
        exported.append((future, took))
        writer = _then(files.povray_writer, export)
        return render_job(job_dir, config, dataclasses.replace(files, povray_writer=writer), progress=progress)

    return_freed_memory()
    result = timed("render", render, own_bars=True)
    future, took = exported[0]
    stats: dict[str, Any] = {}
    if result.scene.ground_height is not None:  # 0 for a grounded object; a hanging one floats
        gap = (ground_height(obj.vertices, gravity) - result.scene.ground_height) * 1000
        stats["ground_gap_mm"] = float(gap) if np.isfinite(gap) else None
    stats.update(object_material=material.to_dict(), render_variant=result.variant, render_integrator=result.integrator,
                 renderer=result.renderer,
                 render_seconds=result.seconds, scene_seconds=result.scene_seconds,
                 render_view_seconds=[round(v, 3) for v in result.view_seconds],
                 denoise_seconds=round(result.denoise_seconds, 3),
                 scene_write_seconds=result.write_seconds, scene_load_seconds=result.load_seconds,
                 scene_wait_seconds=result.wait_seconds,
                 povray_write_cpu_seconds=max(result.povray_write_cpu_seconds - took.get("cpu", 0.0), 0.0))
    # scene.usda (object.usdc, ice.usdc) for DCCs: the render's cameras, sun, sky, materials; the
    # ice's normals those the scene was written with. Its step: what the export raised, if anything
    # (the render waited for its writer thread).
    timed("usd", lambda: future.result(timeout=0))
    stats["usd_write_seconds"] = round(took.get("seconds", 0.0), 3)
    return stats


def _beside(read: Callable[[], Any], write: Callable[[Any], Any]) -> tuple[Future, Callable[[], None], dict]:
    """``read()`` now, in the caller's thread, and ``write(read())`` later in another: the
    future of its result (or of the exception either raised), the function that writes there,
    and the wall and CPU seconds the writing took (once run)."""
    future: Future = Future()
    took: dict[str, float] = {}
    inputs = None
    try:
        inputs = read()
    except Exception as exc:  # raised in the caller's thread by future.result(), at its own step
        future.set_exception(exc)

    def run() -> None:
        if future.done():
            return
        start, cpu = time.perf_counter(), time.thread_time()
        try:
            future.set_result(write(inputs))
        except Exception as exc:
            future.set_exception(exc)
        took.update(seconds=time.perf_counter() - start, cpu=time.thread_time() - cpu)

    return future, run, took


def _then(first: Callable[[], Any] | None, second: Callable[[], Any]) -> Callable[[], None]:
    def both() -> None:
        if first is not None:
            first()
        second()

    return both
