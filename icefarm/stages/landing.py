"""Where the water that leaves the icicles lands: the feet of stalagmites and mounds.

The paper stops at the icicle. But only part of the water that runs down an icicle
freezes on it; the rest drips off its tip, falls straight down and freezes where it
lands (on the ground, or on a lower part of the object: a ledge, a lower basin, a step),
building mounds and stalagmites that may grow up to meet the icicle as a column. This
module finds those landing points; `icefarm.stages.surface.ground_ice` turns them into ice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import arc_lengths, unit
from ..tol import tol
from .trajectories import TrajectoryResult


@dataclass(frozen=True)
class LandingResult:
    """Landing points of the water that drips off the icicles' tips, merged.

    Attributes
    ----------
    positions : (k, 3) float
        Landing points on the object or on the ground plane, in meters.
    normals : (k, 3) float
        Unit normal of the surface at each, turned against gravity (the ground's is -gravity).
    water : (k,) float
        Water that lands there, in meters of water coefficient (the runoff share of the
        water of every tip merged into the point).
    tips : (k, 3) float
        The lowest tip among those that drip onto each point, in meters: what a stalagmite
        grows towards.
    gaps : (k,) float
        Height of ``tips`` above ``positions`` along -gravity, in meters (0 or more): no
        stalagmite may be taller.
    icicles : (k,) int
        Icicle (drip point index) of the tip in ``tips``.
    on_ground : (k,) bool
        On the ground plane (else on the object).
    branch_landing : (b,) int
        Landing point each branch's tip drips onto; -1 for an empty branch or a tip with
        nothing below it (a hanging object's water falls out of the scene).
    """

    positions: np.ndarray
    normals: np.ndarray
    water: np.ndarray
    tips: np.ndarray
    gaps: np.ndarray
    icicles: np.ndarray
    on_ground: np.ndarray
    branch_landing: np.ndarray

    def __len__(self) -> int:
        return len(self.water)


@dataclass(frozen=True)
class LandingOptions:
    """How the drops off the tips fall and gather (`find_landings`).

    Attributes
    ----------
    runoff : float
        Share of an icicle's water that drips off its tips, in [0, 1] (``ground_ice.runoff``).
    merge : float
        Landing points closer than this merge, meters (0: none merge; ``ground_ice.merge``).
    floor : float, optional
        Height of the ground plane along -gravity (a grounded object); None: no ground.
    """

    runoff: float
    merge: float
    floor: float | None = None


def find_landings(traj: TrajectoryResult, drip_water: np.ndarray, gravity, options: LandingOptions, *,
                  cast=None, face_normals: np.ndarray | None = None) -> LandingResult:
    """Follow gravity from every branch tip to the first surface below it.

    Each non-empty branch drips from its tip: ``runoff`` of its icicle's water coefficient
    leaves the icicle, shared among the icicle's branches by their length (a stub of a
    branch sheds little). The drop lands on the first face of the object that ``cast`` sees
    straight below the tip or on the ground at height ``floor``, whichever comes first.
    Landing points closer than ``merge`` become one: greedily, from the wettest down, each
    point takes in every point within ``merge`` of it not yet taken, so points never chain
    along an eave into one, and the points left lie ``merge`` or more apart. A merged point
    keeps the position of its wettest member and the water of all of them.

    Deterministic: no random numbers are drawn.

    Parameters
    ----------
    traj : TrajectoryResult
        Branch polylines, base to tip, in meters.
    drip_water : (i,) float
        Water coefficient of each icicle (`DripResult.water`), meters.
    gravity : (3,) float
        Direction of gravity.
    options : LandingOptions
        The share that runs off, the merge distance and the ground's height.
    cast : callable, optional
        `icefarm.spatial.ray_caster` of the object; None: the object is not looked at.
    face_normals : (f, 3) float, optional
        The object's face normals (for the normal at a landing point); needed with ``cast``.

    Returns
    -------
    LandingResult

    Raises
    ------
    ValueError
        Inconsistent inputs.
    """
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(-1))
    if g.shape != (3,) or not g.any():
        raise ValueError(f"gravity must be 3 numbers, not all zero; got {gravity!r}")
    if cast is not None and face_normals is None:
        raise ValueError("face_normals are needed with cast")
    drip_water = np.asarray(drip_water, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    icicle = np.asarray(traj.branch_icicle, dtype=np.int64)
    if len(icicle) and (icicle.min() < 0 or icicle.max() >= len(drip_water)):
        raise ValueError("trajectories.branch_icicle indexes icicles outside drip_water")
    return _find_landings(traj, off, icicle, drip_water, g, options.runoff, options.merge, cast, face_normals,
                          options.floor)


def _find_landings(traj, off, icicle, drip_water, g, runoff, merge, cast, face_normals, floor):
    nb = len(icicle)
    branch_landing = np.full(nb, -1, dtype=np.int64)
    branches = np.flatnonzero(np.diff(off) > 0)
    pts = np.asarray(traj.points, dtype=np.float64)
    tips = pts[off[branches + 1] - 1]
    water = _tip_water(pts, off, branches, icicle, drip_water, runoff)

    # Fall: the first face below each tip, or the ground, whichever is nearer.
    up = -g
    fall = np.full(len(branches), np.inf)
    normals = np.tile(up, (len(branches), 1))
    if cast is not None and len(branches):
        # Rays start tol.ray_lift_m above each tip, so a tip resting on a surface still sees it.
        distance, face = cast(tips + tol.ray_lift_m * up, np.tile(g, (len(branches), 1)))
        hit = np.isfinite(distance)
        fall[hit] = np.maximum(distance[hit] - tol.ray_lift_m, 0.0)
        n = np.asarray(face_normals, dtype=np.float64)[face[hit]]
        normals[hit] = np.where((n @ up < 0)[:, None], -n, n)  # whatever the winding, facing up
    on_ground = np.zeros(len(branches), dtype=bool)
    if floor is not None:
        to_floor = np.maximum(tips @ up - floor, 0.0)
        on_ground = to_floor <= fall
        fall = np.where(on_ground, to_floor, fall)
        normals[on_ground] = up
    lands = np.isfinite(fall)
    branches, tips, water, fall, normals, on_ground = (
        a[lands] for a in (branches, tips, water, fall, normals, on_ground))
    spots = tips + fall[:, None] * g

    # Merge, wettest first.
    order = np.argsort(-water, kind="stable")
    owner = np.full(len(spots), -1, dtype=np.int64)
    near = cKDTree(spots).query_ball_point(spots, merge) if merge > 0 and len(spots) else None
    seeds = []
    for i in order:
        if owner[i] >= 0:
            continue
        members = [i] if near is None else [j for j in near[i] if owner[j] < 0]
        owner[members] = len(seeds)
        seeds.append(i)
    seeds = np.asarray(seeds, dtype=np.int64)
    k = len(seeds)
    total = np.bincount(owner, weights=water, minlength=k) if k else np.zeros(0)
    # The lowest tip of each merged point is the one a stalagmite rises towards.
    height = tips @ up
    lowest = np.full(k, -1, dtype=np.int64)
    by_height = np.lexsort((height, owner))
    first = np.r_[True, owner[by_height][1:] != owner[by_height][:-1]] if k else np.zeros(0, bool)
    lowest[owner[by_height][first]] = by_height[first]
    branch_landing[branches] = owner
    gaps = np.maximum(height[lowest] - spots[seeds] @ up, 0.0) if k else np.zeros(0)
    return LandingResult(positions=spots[seeds].reshape(-1, 3), normals=unit(normals[seeds]).reshape(-1, 3),
                         water=total, tips=tips[lowest].reshape(-1, 3), gaps=gaps,
                         icicles=icicle[branches[lowest]] if k else np.zeros(0, dtype=np.int64),
                         on_ground=on_ground[seeds], branch_landing=branch_landing)


def _tip_water(pts, off, branches, icicle, drip_water, runoff):
    """``(t,)`` water each branch tip sheds: ``runoff`` of its icicle's water, shared by
    branch length (equally when an icicle's branches have no length)."""
    length = arc_lengths(pts, off)[1][branches]
    ic = icicle[branches]
    n = max(len(drip_water), 1)
    per_icicle = np.bincount(ic, weights=length, minlength=n)
    count = np.bincount(ic, minlength=n)
    share = np.where(per_icicle[ic] > 0, length / np.maximum(per_icicle[ic], 1e-300), 1.0 / np.maximum(count[ic], 1))
    return runoff * drip_water[ic] * share
