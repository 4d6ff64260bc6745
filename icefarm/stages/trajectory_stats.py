"""Shape statistics of icicle trajectories (stage 3): how many segments rise against
gravity, how far branches spread from their parents, how long the trunks are and how much
their lengths vary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import ragged_arange, unit
from .trajectories import TrajectoryResult
from .turtles import row_dot


@dataclass(frozen=True)
class TrajectoryStats:
    """What `measure_trajectories` reports about a `TrajectoryResult`.

    Attributes
    ----------
    upward_share : float
        Fraction of all segments (free growth and slides) that rise against gravity by
        more than `UPWARD_TOLERANCE` of their length; nan without segments.
    branch_spread_mm : float
        Median, over non-trunk branches of `SHAPE_MIN_LENGTH` and more, of the distance
        from the branch tip to its parent polyline, in millimeters; nan without such branches.
    trunk_lengths : (i,) float
        Arc length of each trunk polyline (``branch_parent == -1``), meters.
    length_cv : float
        Coefficient of variation (std / mean) of ``trunk_lengths``; nan for fewer than 2.
    """

    upward_share: float
    branch_spread_mm: float
    trunk_lengths: np.ndarray
    length_cv: float


UPWARD_TOLERANCE = 1e-6  # of a segment's length: rounding, not a rise
# Icicles and branches this long and more (meters) have a shape to measure: their spread,
# taper and whether they hang free. A branch of the last generation or two is a bud a few
# mm long: its tip lies within its own length of the parent, whatever the growth rule.
SHAPE_MIN_LENGTH = 0.03


def measure_trajectories(traj: TrajectoryResult, gravity) -> TrajectoryStats:
    """Shape statistics of trajectories: rising segments, branch spread, trunk lengths.

    Parameters
    ----------
    traj : TrajectoryResult
        Polylines in meters.
    gravity : (3,) float
        Direction of gravity (normalised here).

    Returns
    -------
    TrajectoryStats
    """
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    pts, offsets, parent = traj.points, np.asarray(traj.branch_offsets), np.asarray(traj.branch_parent)
    nb = traj.n_branches
    owner = np.repeat(np.arange(nb), np.diff(offsets))  # (p,) branch of each point
    joins = np.flatnonzero(owner[1:] == owner[:-1])     # segment j runs from point j to j + 1
    seg_a, seg = pts[joins], pts[joins + 1] - pts[joins]
    length = np.linalg.norm(seg, axis=1)
    real = length > 0
    rising = seg[real] @ g < -UPWARD_TOLERANCE * length[real]
    upward_share = float(rising.mean()) if real.any() else float("nan")

    seg_branch = owner[joins]
    per_branch = np.bincount(seg_branch, weights=length, minlength=nb)
    trunk_lengths = per_branch[parent == -1]
    mean = trunk_lengths.mean() if len(trunk_lengths) else 0.0
    length_cv = float(trunk_lengths.std() / mean) if len(trunk_lengths) >= 2 and mean > 0 else float("nan")

    npts = np.diff(offsets)
    # Branches cut away whole (an icicle stopped by the ground) have no points: skip them.
    children = np.flatnonzero((parent >= 0) & (npts > 0) & (per_branch >= SHAPE_MIN_LENGTH))
    children = children[npts[parent[children]] > 0]
    if len(children) == 0:
        return TrajectoryStats(upward_share, float("nan"), trunk_lengths, length_cv)
    seg_count = np.bincount(seg_branch, minlength=nb)
    seg_start = np.r_[0, np.cumsum(seg_count)][:-1]  # segments are stored branch after branch
    tips = pts[offsets[children + 1] - 1]
    # a parent of one point (it ended at once) is a zero-length segment on that point
    one = seg_count[parent[children]] == 0
    dist = np.full(len(children), np.inf)
    dist[one] = np.linalg.norm(tips[one] - pts[offsets[parent[children[one]]]], axis=1)
    todo = np.flatnonzero(~one)
    counts = seg_count[parent[children[todo]]]
    # tip-to-segment distances in chunks of about a million pairs, for memory
    bounds = np.searchsorted(np.cumsum(counts), np.arange(1, counts.sum() // 1_000_000 + 1) * 1_000_000)
    for part in np.split(np.arange(len(todo)), np.unique(bounds)):
        if len(part) == 0:
            continue
        c = counts[part]
        pair = np.repeat(np.arange(len(part)), c)
        within = ragged_arange(c)
        s = seg_start[parent[children[todo[part]]]][pair] + within
        a, ab, tip = seg_a[s], seg[s], tips[todo[part]][pair]
        f = np.divide(row_dot(tip - a, ab), row_dot(ab, ab), out=np.zeros(len(s)), where=length[s] > 0)
        f = np.clip(f, 0.0, 1.0)
        d = np.linalg.norm(a + f[:, None] * ab - tip, axis=1)
        best = np.full(len(part), np.inf)
        np.minimum.at(best, pair, d)
        dist[todo[part]] = best
    return TrajectoryStats(upward_share, float(np.median(dist) * 1000.0), trunk_lengths, length_cv)
