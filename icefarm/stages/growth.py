"""Growth over time, the pure part: a job's stage 1-3 results as they stood at a fraction of
their growth, and the water-driven sizes of stage 4 then (`icefarm.job.frames` runs the frames,
writes and renders them).

Each frame is a prefix of the full growth, so every frame's trajectories are prefixes of the
next frame's and its ice grows out of the one before:

* the trajectories (`trajectories_at`): each branch grows in proportion to time from the
  moment its parent reaches the point it leaves from; a trunk keeps its first ``f L``.
  The width follows from the profile of the *current* length (``r = tip + t L^1/4
  d^3/4``), so the base radius grows as ``t L`` and length grows ``1 / 2t`` (8 at the
  default ``t``) times faster than diameter at every moment, as in nature (8-32);
* the water of each drip point, which sizes the base balls (Equation 2): radii ``∝ f``;
* the glaze (Equation 3): ``minGI`` and ``s`` times ``f``, so its thickness is ``∝ f``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..geometry import arc_lengths
from ..params import GlazeParams, SurfaceParams
from .drips import DripResult
from .trajectories import TrajectoryResult

# Most frames a job's growth may have.
MAX_FRAMES = 240


def trajectories_at(traj: TrajectoryResult, fraction: float) -> TrajectoryResult:
    """The trajectories as they stood at ``fraction`` of their growth.

    A trunk keeps its first ``fraction * L`` meters (L its full length, plus what the ground
    cut from it: an icicle stops at the ground when its growth reaches it, and only then
    gathers ``branch_cut``). A branch is born when its parent's prefix reaches the point it
    leaves from, at fraction ``b``, and then grows in proportion to the time left:
    ``(fraction - b) / (1 - b)`` of its length, so it grows in from nothing instead of
    popping in part-grown, and generations appear in the order the L-system made them.
    A prefix ends on an interpolated point at exactly its length.

    Parameters
    ----------
    traj : TrajectoryResult
        The full growth (stage 3), polylines in meters.
    fraction : float
        In [0, 1]: 0 has no points, 1 returns ``traj`` itself.

    Returns
    -------
    TrajectoryResult
        The same branches (index, icicle, parent), each a prefix of its polyline (empty if
        not yet born); ``branch_cut`` (meters) is what the ground took so far, None when
        ``traj`` has none.
    """
    fraction = float(fraction)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must lie in [0, 1], got {fraction}")
    if fraction == 1.0:
        return traj
    pts = np.asarray(traj.points, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    counts = np.diff(off)
    x, lengths = arc_lengths(pts, off)
    full = lengths + traj.cut
    birth = births(traj, x, full)
    span = 1.0 - birth
    progress = np.clip(np.divide(fraction - birth, span, out=np.zeros_like(span), where=span > 0), 0.0, 1.0)
    grown = full * progress
    kept = np.minimum(grown, lengths)
    alive = (fraction > birth) & (counts > 0)
    owner = np.repeat(np.arange(len(counts)), counts)
    keep = alive[owner] & (x <= kept[owner])
    n_keep = np.bincount(owner[keep], minlength=len(counts))
    # a prefix that ends between two points ends on the point between them
    partial = alive & (kept < lengths) & (n_keep > 0)
    last = off[:-1][partial] + n_keep[partial] - 1
    t = (kept[partial] - x[last]) / (x[last + 1] - x[last])
    new_off = np.r_[0, np.cumsum(n_keep + partial)].astype(np.int64)
    out = np.empty((new_off[-1], 3))
    src = np.flatnonzero(keep)
    out[new_off[:-1][owner[src]] + src - off[:-1][owner[src]]] = pts[src]
    out[new_off[1:][partial] - 1] = pts[last] + t[:, None] * (pts[last + 1] - pts[last])
    cut = None if traj.branch_cut is None else np.where(alive, grown - kept, 0.0)
    return TrajectoryResult(points=out, branch_offsets=new_off, branch_icicle=traj.branch_icicle,
                            branch_parent=traj.branch_parent, branch_cut=cut, branch_growth=traj.branch_growth)


def stage4_inputs_at(drips: DripResult, glaze: GlazeParams,
                     fraction: float) -> tuple[DripResult, GlazeParams]:
    """The water-driven sizes of stage 4 at ``fraction`` of the growth.

    Returns ``drips`` with ``water`` times ``fraction`` (base ball radii, Equation 2, are
    proportional to it; they stay capped by the current icicle's root) and ``glaze`` with
    ``min_radius`` and ``scale`` times ``fraction`` (Equation 3's thickness, meters, is
    then proportional to it). Positions, counts and the wet area do not change, so every
    random draw lands where the full growth's does. ``fraction`` 1 returns the inputs.
    """
    if fraction == 1.0:
        return drips, glaze
    scaled = dataclasses.replace(glaze, min_radius=glaze.min_radius * fraction, scale=glaze.scale * fraction)
    return dataclasses.replace(drips, water=np.asarray(drips.water, dtype=np.float64) * fraction), scaled


def frame_fractions(frames: int) -> np.ndarray:
    """``(frames,)`` fractions of the growth, ``1/frames`` to exactly 1."""
    if not 1 <= frames <= MAX_FRAMES:
        raise ValueError(f"frames must lie in [1, {MAX_FRAMES}], got {frames}")
    return np.arange(1, frames + 1) / frames


def births(traj: TrajectoryResult, x: np.ndarray, full: np.ndarray) -> np.ndarray:
    """``(b,)`` fraction of the growth at which each branch starts: 0 for trunks; for a branch,
    when its parent's prefix reaches the parent point it leaves from (its nearest)."""
    pts, off = np.asarray(traj.points, dtype=np.float64), np.asarray(traj.branch_offsets, dtype=np.int64)
    parent = np.asarray(traj.branch_parent, dtype=np.int64)
    birth = np.zeros(traj.n_branches)
    for b in np.flatnonzero(parent >= 0):  # parents come before their branches (stage 3 appends them)
        q = parent[b]
        if off[b + 1] == off[b] or off[q + 1] == off[q] or full[q] <= 0:
            birth[b] = 1.0 if off[b + 1] == off[b] else birth[q]
            continue
        at = off[q] + np.argmin(np.linalg.norm(pts[off[q]:off[q + 1]] - pts[off[b]], axis=1))
        birth[b] = birth[q] + (1.0 - birth[q]) * min(x[at] / full[q], 1.0)
    return birth


def noise_draws(traj: TrajectoryResult, surface: SurfaceParams) -> int:
    """How many doubles stage 4 draws for the icicles' noise before the bases' and glaze's
    draws: `icefarm.stages.surface.icicles.icicle_balls` takes two per ball (radius and
    angle) when ``surface.noise`` is on. Every frame's stream is advanced by the full
    growth's count less its own, so its bases and glaze draw what the full growth's do
    (PCG64 turns one 64-bit step into one double)."""
    if surface.mode == "tubes" or surface.noise <= 0:
        return 0
    from .surface.icicles import icicle_balls

    return 2 * len(icicle_balls(traj, surface, np.random.default_rng(0)))
