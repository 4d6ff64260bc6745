"""``scene.json``: the rendered scene described once, for every writer that is not Mitsuba's.

`icefarm.scene.write.write_scenes` writes it beside ``scene.xml`` from the same values
(cameras, views, sky, sun, ground, the ice's look, the object's material, gravity, the
meshes' files); the USD and glTF exports (`icefarm.rendered.read_rendered`) read it instead
of parsing ``scene.xml`` back. Values every writer shares (the sun's irradiance, the sky's
scale, the ground's square and colour) come from the functions here, which ``scene.xml``'s
writer calls too. Lengths in meters, colours linear RGB, angles in degrees.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

SPEC_FILE = "scene.json"
SPEC_VERSION = 1
SUN_WARMTH = (1.0, 0.93, 0.84)  # the sun's colour (a late-morning white)


def sun_irradiance(environment) -> np.ndarray:
    """(3,) the sun's irradiance, W/m^2 in Mitsuba's scale: warm white times its strength
    and the exposure."""
    return np.asarray(SUN_WARMTH) * environment.sun_strength * 2.0 ** environment.exposure


def sky_scale(environment) -> float:
    """The sky image's radiance scale: its strength times the exposure."""
    return float(environment.sky_strength * 2.0 ** environment.exposure)


def ground_corners(ground) -> np.ndarray:
    """(4, 3) corners of the ground square (`icefarm.scene.mitsuba.Ground`), counter-clockwise
    seen from above: Mitsuba's rectangle (local X to front, Y to right) at (+-1, +-1)."""
    right, _, front = np.asarray(ground.frame, dtype=np.float64)
    hs, centre = ground.half_size, np.asarray(ground.centre, dtype=np.float64)
    local = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    return centre + local[:, :1] * front * hs + local[:, 1:] * right * hs


def ground_color(environment) -> np.ndarray:
    """(3,) the ground's matte colour: the checker's mean, or the plain ground's."""
    from .config import GROUND_CHECKER, GROUND_PLAIN

    return np.mean(GROUND_CHECKER, axis=0) if environment.ground == "checker" else np.asarray(GROUND_PLAIN)


def scene_spec(config, cameras: Sequence, frame: np.ndarray, *, gravity, object_ply: str, ice_ply: str | None,
               ice_flip: bool, sky_file: str, sun_dir: np.ndarray, ground, material, medium) -> dict:
    """The JSON-ready description of a job's rendered scene (see the module docstring)."""
    env = config.environment
    sun = env.sun_strength > 0
    ice = None
    if ice_ply is not None:
        ice = {"file": ice_ply, "flip": bool(ice_flip), "ior": config.ice.ior, "alpha": config.ice.roughness,
               "tint": list(config.ice.tint),
               "absorption": list(medium.absorption) if medium is not None else [0.0, 0.0, 0.0],
               "scattering": float(medium.scattering) if medium is not None else 0.0}
    return {
        "version": SPEC_VERSION,
        "resolution": [config.width, config.height],
        "views": [{"name": v.name, "frame": v.frame} for v in config.views],
        "cameras": [{"origin": _list(c.origin), "target": _list(c.target), "up": _list(c.up), "fov_x": c.fov_x,
                     "fov_y": c.fov_y, "near": c.near, "far": c.far} for c in cameras],
        "gravity": _list(np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity)),
        "sky": {"file": sky_file, "scale": sky_scale(env), "frame": np.asarray(frame, dtype=np.float64).tolist()},
        "sun": {"direction": _list(np.asarray(sun_dir) / np.linalg.norm(sun_dir)),
                "irradiance": _list(sun_irradiance(env))} if sun else None,
        "ground": {"corners": ground_corners(ground).tolist(), "color": _list(ground_color(env))}
        if ground is not None else None,
        "object": {"file": object_ply, "material": material.to_dict()},
        "ice": ice,
    }


def write_spec(path: str | Path, spec: dict) -> None:
    from ..artifacts import atomic_write

    atomic_write(Path(path), json.dumps(spec, indent=1) + "\n")


def read_spec(path: str | Path) -> dict:
    return json.loads(Path(path).read_text())


def _list(v) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=np.float64).reshape(-1)]
