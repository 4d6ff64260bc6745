"""Benchmark drivers behind `icefarm bench`: medians over repeated runs."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .mesh import prepare
from .stages.drips import find_drips
from .stages.trajectories import grow_trajectories
from .stages.water import compute_water


@dataclass(frozen=True)
class StageRuns:
    faces: int
    icicles: int
    ice_faces: int
    seconds: dict  # stage -> list of seconds, one per run


def stage_timings(mesh_path: str, size_m: float, p: dict, repeat: int, surface: bool = False) -> StageRuns:
    """Time stages 1-3 (and 4) ``repeat`` times on a fresh copy of the mesh each run.

    Mesh loading is excluded; the ray-tracing BVH is built on a copy first, as a
    long-lived worker would have it, so each run times the stages alone.
    """
    prepared = prepare(mesh_path, size_m, p["water"]["gravity"])
    g = np.asarray(p["water"]["gravity"], dtype=np.float64)
    g /= np.linalg.norm(g)
    names = ["water", "drips", "trajectories"] + (["surface"] if surface else [])
    seconds: dict[str, list[float]] = {name: [] for name in names}
    icicles = ice_faces = 0
    for run in range(repeat):
        mesh = prepared.mesh.copy()
        mesh.ray.intersects_any(mesh.vertices[:1] + 1.0, np.array([g]))  # build the BVH
        rng = np.random.default_rng(run)
        t0 = time.perf_counter()
        water = compute_water(mesh, g, p["water"]["rays"], p["water"]["influence_radius"], rng)
        t1 = time.perf_counter()
        drips = find_drips(mesh, water.water, g, p["drips"]["count"], p["drips"]["drip_limit"], rng)
        t2 = time.perf_counter()
        traj = grow_trajectories(mesh, drips.positions, mesh.face_normals[drips.faces], drips.water, g, rng,
                                 drip_limit=p["drips"]["drip_limit"], **p["trajectories"])
        t3 = time.perf_counter()
        for name, dt in zip(names, (t1 - t0, t2 - t1, t3 - t2)):
            seconds[name].append(dt)
        icicles = len(drips.positions)
        if surface:
            from .stages.surface import build_ice

            t4 = time.perf_counter()
            ice = build_ice(mesh, mesh, water, drips, traj, p["surface"], p["glaze"], g, rng)
            seconds["surface"].append(time.perf_counter() - t4)
            ice_faces = len(ice.faces)
    return StageRuns(len(prepared.mesh.faces), icicles, ice_faces, seconds)
