"""The glaze as measured on the finished ice: coverage of the wet surface, thickness along
its normal, top/bottom balance and relief (`measure_glaze`).

A pure measurement: any ice mesh (coat, metaballs, with icicles) can be measured against the
surface the glaze grew on and its water (a `CoatSurface`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ...geometry import sample_faces, unit
from ...spatial import near_caster, ray_caster
from ...tol import tol
from .glaze import CoatSurface, wet_vertices

# measure_glaze: rays start `tol.ray_under_m` under the surface and count ice that starts
# within REACH (m) above it.
REACH = 0.01
# `measure_glaze` builds its first tree over the ice this far along its rays (meters): past
# the thickest coats the storms lay (25 mm is crippling), so few rays need a second round.
GLAZE_CAST_REACH = 0.05
# ... on ice of more faces than this; under it the whole tree is as quick (its 20,000 rays:
# near_caster is even with the whole tree on the fountain's 0.84 M faces, slower on the
# bunny's 0.22 M, nearly twice as fast on the bench's 2.2 M and the car's 2.4 M).
NEAR_CASTER_FACES = 1_000_000

@dataclass(frozen=True)
class GlazeProbe:
    """How `measure_glaze` samples the wet surface.

    Attributes
    ----------
    samples : int
        Points drawn area-weighted on the wet faces.
    reach : float
        Ice that starts within this distance above a point covers it, in meters.
    seed : int
        Seed of the points' draw (the same points for the same inputs).
    """

    samples: int = 20000
    reach: float = REACH
    seed: int = 0


@dataclass(frozen=True)
class GlazeStats:
    """The glaze as measured on the finished ice (`measure_glaze`).

    Attributes
    ----------
    coverage : float
        Share of the wet surface with ice over it, 0 to 1 (nan: nothing wet).
    p10_mm, p50_mm, p90_mm : float
        Thickness of the ice along the surface normal over the covered points, in
        millimeters (nan: nothing covered).
    top_bottom : float
        Median thickness (uncovered points count as 0) over the top third of the wet
        surface's height range, along -gravity, over that of the bottom third (nan when
        both are 0, inf when only the bottom is).
    wet_area_m2 : float
        Area of the wet faces, in square meters.
    samples : int
        Points measured.
    relief : float
        Runnels and frozen drops on steep faces (`RELIEF_STEEP`): the median over their
        points of how far the glaze's thickness strays from the ice the storm froze there,
        as a share of it (an even coat: the marching's few percent; runnels: 0.15 and more).
        nan: no storm in physical units, or no such points.
    """

    coverage: float
    p10_mm: float
    p50_mm: float
    p90_mm: float
    top_bottom: float
    wet_area_m2: float
    samples: int
    relief: float = math.nan


# `glaze_relief`: faces whose normal lies within this cosine of level (steeper than 60
# degrees), where the storm froze this much ice at least (m).
RELIEF_STEEP = 0.5
RELIEF_MIN_ICE = 0.003


def measure_glaze(ice_vertices: np.ndarray, ice_faces: np.ndarray, surface: CoatSurface, gravity,
                  probe: GlazeProbe = GlazeProbe(), cast=None) -> GlazeStats:
    """Coverage, thickness and top/bottom balance of the glaze on the finished ice.

    ``probe.samples`` points are drawn area-weighted on the wet faces (at least two wet
    vertices, none excluded; the same random points for the same inputs). From each, a ray
    leaves from just under the surface along the face's outward normal: the point is covered
    when it starts inside the ice or enters it within ``probe.reach``; the thickness is the
    length of that first stretch of ice above the surface. A pure measurement: any ice
    mesh (coat, metaballs, with icicles) can be measured against any water.

    Parameters
    ----------
    ice_vertices : (n, 3) float
        In meters.
    ice_faces : (m, 3) int
        Outward-wound, closed.
    surface : CoatSurface
        The surface the glaze grew on (``mesh``), its water (per vertex of ``mesh``) and
        the vertices that are not glazed on purpose (``exclude``, left out of the wet surface).
    gravity : (3,) float
    probe : GlazeProbe
        How many points, how far above them ice counts, the seed of their draw.
    cast : callable, optional
        An `icefarm.spatial.ray_caster` of the ice mesh, if one is at hand (building one
        takes time in proportion to the ice's faces).

    Returns
    -------
    GlazeStats
    """
    flow_mesh, water, exclude = surface.mesh, surface.water, surface.exclude
    faces = np.asarray(flow_mesh.faces)
    wet = wet_vertices(water, exclude)
    ok = wet[faces].sum(axis=1) >= 2
    if exclude is not None:
        ok &= ~np.asarray(exclude, dtype=bool)[faces].any(axis=1)
    wet_faces = np.flatnonzero(ok)
    area = float(flow_mesh.area_faces[wet_faces].sum())
    nan = math.nan
    if area <= 0:
        return GlazeStats(nan, nan, nan, nan, nan, 0.0, 0)
    pts, face, bary = sample_faces(flow_mesh, wet_faces, probe.samples, np.random.default_rng(probe.seed))
    normal = flow_mesh.face_normals[face]
    thick = np.zeros(len(pts))
    if len(ice_faces):
        thick = _ice_above(np.asarray(ice_vertices, dtype=np.float64), np.asarray(ice_faces), pts, normal,
                           probe.reach, cast)
    covered = thick > 0
    h = pts @ -unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    lo, hi = h.min() + np.ptp(h) / 3, h.max() - np.ptp(h) / 3
    top, bottom = float(np.median(thick[h >= hi])), float(np.median(thick[h <= lo]))
    ratio = top / bottom if bottom > 0 else (math.inf if top > 0 else nan)
    p10, p50, p90 = (np.quantile(thick[covered], [0.1, 0.5, 0.9]) * 1000) if covered.any() else (nan,) * 3
    relief = nan
    if water.storm is not None:
        storm_ice = np.einsum("kc,kc->k", bary, np.asarray(water.storm.ice, dtype=np.float64)[faces[face]])
        relief = glaze_relief(normal, thick, storm_ice, gravity)
    return GlazeStats(float(covered.mean()), float(p10), float(p50), float(p90), ratio, area, len(pts), relief)


def _ice_above(ice_vertices: np.ndarray, ice_faces: np.ndarray, pts: np.ndarray, normal: np.ndarray, reach: float,
               cast) -> np.ndarray:
    """(k,) meters of ice along ``normal`` (k, 3) above each of ``pts`` (k, 3): the first
    stretch of it, where the point starts inside it or it starts within ``reach``; else 0."""
    if cast is None:  # on big ice, a tree over the faces near the rays only: most stop in the coat
        cast = near_caster(ice_vertices, ice_faces, GLAZE_CAST_REACH) if len(ice_faces) > NEAR_CASTER_FACES \
            else ray_caster(trimesh.Trimesh(ice_vertices, ice_faces, process=False))
    thick = np.zeros(len(pts))
    start, past = tol.ray_under_m, tol.ray_past_m
    d1, f1 = cast(pts - start * normal, normal)
    hit = np.flatnonzero(np.isfinite(d1))
    tri = ice_vertices[ice_faces[f1[hit]]]
    facing = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # outward, unnormalised
    leaving = np.zeros(len(pts), dtype=bool)
    leaving[hit] = np.einsum("kd,kd->k", facing, normal[hit]) > 0
    # Inside the ice at the surface: the ice above it ends where the ray leaves.
    inside = leaving & (d1 > start)
    thick[inside] = d1[inside] - start
    # Outside it: ice that starts within reach, as thick as the ray stays in it.
    enter = np.flatnonzero(~leaving & np.isfinite(d1) & (d1 - start <= reach))
    if len(enter):
        d2, _ = cast(pts[enter] + (d1[enter] - start + past)[:, None] * normal[enter], normal[enter])
        thick[enter] = np.where(np.isfinite(d2), d2 + past, 0.0)
    return thick


def glaze_relief(normals: np.ndarray, thickness: np.ndarray, storm_ice: np.ndarray, gravity) -> float:
    """`GlazeStats.relief` of glaze ``thickness`` (k,) meters measured at surface points of
    unit ``normals`` (k, 3) where the storm froze ``storm_ice`` (k,) meters."""
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    steep = (np.abs(normals @ g) < RELIEF_STEEP) & (thickness > 0) & (storm_ice >= RELIEF_MIN_ICE)
    if steep.sum() < 10:
        return math.nan
    return float(np.median(np.abs(thickness[steep] / storm_ice[steep] - 1.0)))
