"""Where a storm's rain comes from and where it lands: along gravity in still air, slanted
by the wind (driving rain) otherwise.

A raindrop falls at about `FALL_SPEED` and drifts with the wind, so it travels along
``g + W / v`` (``g`` the unit gravity, ``W`` the wind's velocity across it, ``v`` the fall
speed). A face of outward normal ``n`` then catches ``P max(-n . (g + W / v), 0)`` of water
per area for a precipitation depth ``P`` (the depth a level face gets): a level top still
gets ``P`` whatever the wind, a wall facing the wind gets ``P |W| / v``, the lee gets none.
That is Jones's wind term (Atmospheric Research 46, 87-97, 1998: a bar's ice grows with
the precipitation and with the wind speed times the liquid water content of the air) read
per face, and why signs, fences and walls glaze on their windward side in a real storm.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ..geometry import unit
from ..tol import tol

# Fall speed of freezing rain (m/s): the ratio of Jones's two terms, P over the wind speed
# times the liquid water content 0.067 P^0.846 g/m^3 (P in mm/h), is 4.6 to 5.3 m/s at 1 to
# 5 mm/h; Gunn & Kinzer (1949) measured 4 m/s for a 1 mm drop, 6.5 m/s for 2 mm.
FALL_SPEED = 5.0


def rain_vector(gravity, wind) -> np.ndarray:
    """``(3,)`` the rain's path per meter of fall: ``g + W / FALL_SPEED``, ``g`` the unit
    ``gravity`` and ``W`` the part of ``wind`` (m/s) across it; exactly ``g`` in still air."""
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    w = np.asarray(wind, dtype=np.float64).reshape(3)
    across = w - (w @ g) * g
    if not across.any():
        return g
    return g + across / FALL_SPEED


def open_sky(mesh: trimesh.Trimesh, rain, cast) -> np.ndarray:
    """``(n,) bool``: a ray from each vertex (lifted a hair along its normal) back up the
    ``rain`` (`rain_vector`, or the gravity for still air) leaves the object. ``cast`` is a
    `icefarm.spatial.ray_caster` of ``mesh``."""
    back = -unit(np.asarray(rain, dtype=np.float64).reshape(3))
    eps = tol.hair * float(np.linalg.norm(mesh.extents))
    lifted = mesh.vertices + eps * mesh.vertex_normals + eps * back
    return ~np.isfinite(cast(lifted, np.broadcast_to(back, lifted.shape))[0])


def facing_rain(normals: np.ndarray, rain) -> np.ndarray:
    """``(n,)`` water caught per area, as a share of the precipitation depth, by faces of
    unit outward ``normals`` (n, 3) under open sky: ``max(-n . rain, 0)``."""
    return np.maximum(np.asarray(normals, dtype=np.float64) @ -np.asarray(rain, dtype=np.float64), 0.0)
