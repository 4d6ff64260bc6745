"""Where an object stands: on the ground, or hanging (a sign, a branch, a lamp).

A grounded object's lowest point rests on the ground plane; the faces it stands on get no
icicle, base or glaze, and an icicle that would reach the ground stops at it. A hanging
object keeps the ground below its lowest ice.
"""

from __future__ import annotations

import enum

import numpy as np
import trimesh

from .stages.trajectories import TrajectoryResult


class Placement(enum.Enum):
    GROUND = "ground"
    HANGING = "hanging"


PLACEMENTS = tuple(p.value for p in Placement)


def ground_height(vertices: np.ndarray, gravity) -> float:
    """Height (m, along -gravity) of the lowest of ``vertices`` (n, 3): the ground under it."""
    g = np.asarray(gravity, dtype=np.float64)
    return float((np.asarray(vertices, dtype=np.float64) @ -(g / np.linalg.norm(g))).min())


def sole_vertices(vertices: np.ndarray, gravity, clearance: float) -> np.ndarray:
    """``(n,) bool``: vertices within ``clearance`` of the object's height above its lowest
    point, where it rests on the ground (no icicle, base or glaze there)."""
    g = np.asarray(gravity, dtype=np.float64)
    heights = np.asarray(vertices, dtype=np.float64) @ -(g / np.linalg.norm(g))
    return heights < heights.min() + clearance * np.ptp(heights)


def stop_at_ground(traj: TrajectoryResult, gravity, floor: float, margin: float) -> TrajectoryResult:
    """Icicles cut where they come within ``margin`` of the ground at height ``floor``.

    Each branch keeps its points down to the last one above ``floor + margin`` (the drop at
    the tip then just touches the ground), and ends exactly there; a branch that starts
    below it is left empty (no points), so branch indices keep their meaning. The length
    each branch lost is its ``branch_cut``: the water that would have lengthened it
    thickens it instead (a column foot on the ground, not a straw).

    Parameters
    ----------
    traj : TrajectoryResult
    gravity : (3,) float
    floor, margin : float
        Ground height along -gravity and the clearance to keep (the tip radius), meters.
    """
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    pts = np.asarray(traj.points, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    limit = floor + margin
    height = pts @ -g
    if len(pts) == 0 or height.min() >= limit:
        return traj
    kept, counts = [], []
    cut = traj.cut.copy()
    for b in range(len(off) - 1):
        branch, h = pts[off[b]:off[b + 1]], height[off[b]:off[b + 1]]
        low = np.flatnonzero(h < limit)
        if len(branch) == 0 or len(low) == 0:  # untouched: no cut (its length less itself is 0)
            kept.append(branch)
            counts.append(len(branch))
            continue
        if low[0] == 0:  # a branch of an icicle already cut: nothing of it is left
            kept.append(branch[:0])
        else:
            i = low[0]
            t = (h[i - 1] - limit) / max(h[i - 1] - h[i], 1e-300)
            kept.append(np.vstack([branch[:i], branch[i - 1] + t * (branch[i] - branch[i - 1])]))
        cut[b] += _polyline_length(branch) - _polyline_length(kept[-1])
        counts.append(len(kept[-1]))
    return TrajectoryResult(points=np.concatenate(kept) if kept else np.zeros((0, 3)),
                            branch_offsets=np.r_[0, np.cumsum(counts)].astype(np.int64),
                            branch_icicle=traj.branch_icicle, branch_parent=traj.branch_parent,
                            branch_cut=cut, branch_growth=traj.branch_growth)


def _polyline_length(points: np.ndarray) -> float:
    # One polyline on its own, not `icefarm.geometry.arc_lengths` of all branches: that
    # differences a running sum over every branch, which would leave ~1e-13 m of cut on the
    # branches the ground never reached (cut > 0 gives an icicle a foot); and arc_lengths of
    # each branch alone sums in order, not pairwise as np.sum, which changes the cut lengths
    # in their last bits, and the meshes with them.
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def ground_level(placement: str, obj: trimesh.Trimesh, gravity) -> float | None:
    """Height of the ground plane: under the object's lowest point for a grounded object;
    None (below the lowest ice, the scene's own choice) for a hanging one."""
    return ground_height(obj.vertices, gravity) if placement == Placement.GROUND.value else None
