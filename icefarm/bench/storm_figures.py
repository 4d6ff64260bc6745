"""The figures a storm is judged by, measured on a finished job: how many icicles, how
long, how close together, and how much of what the rain reaches is glazed, how thickly.

* Rain-reached points (`rain_reached_points`): points sampled by area on the faces whose
  normal rises more than ``min_up`` against gravity and whose ray against gravity escapes
  the object (open sky).
* Glaze along the normal (`ice_along_normals`): the ice lying above each of those points,
  along its normal; `glaze_coverage` turns it into the share glazed and the median.
* Nearest icicle (`nearest_root_distance`): for each icicle root the distance to the
  nearest other root, the median of those.

`storm_figures` gathers all of them into a `StormFigures`. Pure measurements: meshes in
meters, arrays and a seeded generator in, numbers out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry import sample_faces, unit
from ..spatial import ray_caster
from ..stages.trajectories import TrajectoryResult
from ..stages.trajectory_stats import measure_trajectories
from ..tol import tol

# A point is glazed when more than this much ice (m) lies along its normal.
GLAZED = 2e-4


@dataclass(frozen=True)
class StormFigures:
    """The storm figures of one job (`storm_figures`).

    Attributes
    ----------
    icicles : int
        Icicles: trunks (``branch_parent == -1``) with at least one point.
    median_trunk_m : float
        Median arc length of those trunks' polylines, meters (nan without icicles).
    nearest_root_m : float
        Median over icicle roots of the distance to the nearest other root, meters (nan
        for fewer than 2 icicles).
    glaze_coverage : float
        Share of the rain-reached points with more than `GLAZED` of ice along their normal,
        0 to 1 (nan: the rain reaches nothing).
    glaze_p50_m : float
        Median of that thickness over all rain-reached points, bare ones as 0, meters.
    rain_points : int
        Rain-reached points measured.
    """

    icicles: int
    median_trunk_m: float
    nearest_root_m: float
    glaze_coverage: float
    glaze_p50_m: float
    rain_points: int


def rain_reached_points(mesh: trimesh.Trimesh, gravity, count: int, rng: np.random.Generator,
                        min_up: float = 0.3, *, cast=None) -> tuple[np.ndarray, np.ndarray]:
    """Points of the surface that vertical rain reaches: facing up and under open sky.

    ``count`` points are drawn by area (`icefarm.geometry.sample_faces`) on the faces whose
    unit normal has a component against gravity over ``min_up``; those whose ray against
    gravity, from `tol.ray_lift_m` off the face along its normal, hits the object are left out
    (something above shades them).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, outward-facing, meters.
    gravity : (3,) float
        Direction of gravity (normalised here).
    count : int
        Points drawn before the shaded ones are left out.
    rng : numpy.random.Generator
    min_up : float
        Cosine of the steepest tilt from horizontal that counts as facing up (0.3: up to
        about 73 degrees).
    cast : callable, optional
        An `icefarm.spatial.ray_caster` of ``mesh``, if one is at hand.

    Returns
    -------
    points : (k, 3) float
        On the surface, meters; ``k <= count``.
    normals : (k, 3) float
        Unit outward normal of each point's face.
    """
    up = -_unit_gravity(gravity)
    faces = np.flatnonzero(mesh.face_normals @ up > min_up)
    points, face, _ = sample_faces(mesh, faces, count, rng)
    normals = np.asarray(mesh.face_normals[face], dtype=np.float64)
    if len(points) == 0:
        return points, normals.reshape(0, 3)
    if cast is None:
        cast = ray_caster(mesh)
    distance, _ = cast(points + tol.ray_lift_m * normals, np.broadcast_to(up, points.shape))
    sky = ~np.isfinite(distance)
    return points[sky], normals[sky]


def ice_along_normals(ice_mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray,
                      reach: float = 0.1, *, cast=None) -> np.ndarray:
    """Thickness of the ice lying along each normal above a surface point, in meters.

    A ray leaves each point from `tol.ray_under_m` under the surface along its normal, into a closed,
    outward-facing ice mesh (the glaze coat fused with the icicles; the coat's inner side
    lies inside the object):

    * its first face is one it leaves the ice by: the point is under ice, as thick as from
      the surface point to that exit;
    * its first face is one it enters by, within ``reach`` of the surface: ice lies a
      little above the point (a coat that does not reach into the object, a separate
      mesh): as thick as the ray stays in it;
    * otherwise 0.

    The rule of `icefarm.stages.surface.glaze_measure.measure_glaze`, on given points.

    Parameters
    ----------
    ice_mesh : trimesh.Trimesh or None
        Closed, outward-facing, meters; None or no faces: no ice.
    points : (k, 3) float
        On the object's surface, meters.
    normals : (k, 3) float
        Unit outward normals of the object there.
    reach : float
        Meters above the surface within which ice must start.
    cast : callable, optional
        An `icefarm.spatial.ray_caster` of ``ice_mesh``, if one is at hand.

    Returns
    -------
    (k,) float
        Meters, 0 where no ice lies along the normal.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    thick = np.zeros(len(points))
    if ice_mesh is None or len(ice_mesh.faces) == 0 or len(points) == 0:
        return thick
    if cast is None:
        cast = ray_caster(ice_mesh)
    start, past = tol.ray_under_m, tol.ray_past_m
    d1, f1 = cast(points - start * normals, normals)
    hit = np.isfinite(d1)
    # Leaving the ice: the face met faces along the ray (outward-wound mesh).
    leaving = np.zeros(len(points), dtype=bool)
    leaving[hit] = np.einsum("kd,kd->k", ice_mesh.face_normals[f1[hit]], normals[hit]) > 0
    under = leaving & (d1 > start)
    thick[under] = d1[under] - start
    enter = np.flatnonzero(hit & ~leaving & (d1 - start <= reach))
    if len(enter):
        # Re-cast from just past the entry: the length of the stretch of ice.
        d2, _ = cast(points[enter] + (d1[enter] - start + past)[:, None] * normals[enter], normals[enter])
        thick[enter] = np.where(np.isfinite(d2), d2 + past, 0.0)
    return thick


def glaze_coverage(thickness: np.ndarray, threshold: float = GLAZED) -> tuple[float, float]:
    """Share of points glazed, and the median thickness.

    Parameters
    ----------
    thickness : (k,) float
        Ice along the normal of each rain-reached point (`ice_along_normals`), meters.
    threshold : float
        Meters of ice over which a point counts as glazed (`GLAZED`: 0.2 mm).

    Returns
    -------
    share : float
        Points with more than ``threshold``, 0 to 1 (nan for no points).
    p50 : float
        Median of ``thickness`` over all the points, bare ones included as they are (what
        glaze p50 means: the median of that thickness), meters; so it is 0 when under
        half the points are glazed. nan for no points.
    """
    thickness = np.asarray(thickness, dtype=np.float64).reshape(-1)
    if len(thickness) == 0:
        return math.nan, math.nan
    return float(np.mean(thickness > threshold)), float(np.median(thickness))


def nearest_root_distance(roots: np.ndarray) -> float:
    """Median over icicle roots of the distance to the nearest other root, in meters.

    Parameters
    ----------
    roots : (k, 3) float
        Where each icicle leaves the object, meters.

    Returns
    -------
    float
        nan for fewer than 2 roots.
    """
    from scipy.spatial import cKDTree

    roots = np.asarray(roots, dtype=np.float64).reshape(-1, 3)
    if len(roots) < 2:
        return math.nan
    distance, _ = cKDTree(roots).query(roots, k=2)  # the first neighbour is the root itself
    return float(np.median(distance[:, 1]))


def storm_figures(obj_mesh: trimesh.Trimesh, ice_mesh: trimesh.Trimesh | None, trajectories: TrajectoryResult,
                  gravity, rng: np.random.Generator, count: int = 4000) -> StormFigures:
    """The storm figures of a job: icicles, trunk length, nearest root, glaze where rain reaches.

    Parameters
    ----------
    obj_mesh : trimesh.Trimesh
        The object, outward-facing, meters.
    ice_mesh : trimesh.Trimesh or None
        All the ice (coat and icicles), closed, outward-facing, meters.
    trajectories : TrajectoryResult
        The icicles' polylines, meters.
    gravity : (3,) float
        Direction of gravity.
    rng : numpy.random.Generator
        Draws the rain-reached points.
    count : int
        Points drawn on the upward faces (`rain_reached_points`).

    Returns
    -------
    StormFigures
    """
    if count < 0:
        raise ValueError(f"count must be 0 or more, got {count}")
    all_trunks = np.flatnonzero(np.asarray(trajectories.branch_parent) == -1)
    offsets = np.asarray(trajectories.branch_offsets)
    # The ground may cut a trunk away whole: no points, no icicle.
    has_points = offsets[all_trunks + 1] > offsets[all_trunks]
    trunks = all_trunks[has_points]
    # trunk_lengths: the polylines' arc lengths, in branch order as ``all_trunks``.
    kept = measure_trajectories(trajectories, gravity).trunk_lengths[has_points]
    roots = np.asarray(trajectories.points, dtype=np.float64).reshape(-1, 3)[offsets[trunks]]
    points, normals = rain_reached_points(obj_mesh, gravity, count, rng)
    share, p50 = glaze_coverage(ice_along_normals(ice_mesh, points, normals))
    return StormFigures(icicles=len(trunks),
                        median_trunk_m=float(np.median(kept)) if len(kept) else math.nan,
                        nearest_root_m=nearest_root_distance(roots),
                        glaze_coverage=share, glaze_p50_m=p50, rain_points=len(points))


def _unit_gravity(gravity) -> np.ndarray:
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    if not np.any(g):
        raise ValueError("gravity must be a non-zero (3,) vector")
    return g
