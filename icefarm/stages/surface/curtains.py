"""Curtains: sheets of ice between icicles that hang close together (``surface.curtain``).

Along a real eave, water running between neighbouring icicles freezes into webs that join
them: thick where they leave the eave, thinning downwards, draped between the two. Each
pair of trunks whose bases lie closer than ``surface.curtain`` (neighbours only: a pair
with another base between them is left to that one) gets a sheet of metaballs
(`sheet_balls`) spanning them at matching heights, from the lower base down to the
shorter trunk's tip or to where the trunks part further than ``surface.curtain``. The
sheet is `CURTAIN_SHARE` of the trunks' mean radius thick on each side, and its lower
edge drapes up between the trunks (`DRAPE`). Its balls join the icicles' field.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from ...geometry import arc_lengths, ragged_arange, unit
from ...metaballs.balls import NO_BALLS, Balls, concat_balls, sheet_balls
from ...params import SurfaceParams
from ...tol import tol
from ..trajectories import TrajectoryResult
from .profile import grown_lengths, profile_args, smooth_radius

# Half the sheet's thickness over the mean radius of its two trunks at that height: thick
# near the bases, thin towards the tips, as the icicles themselves.
CURTAIN_SHARE = 0.2
# Midway between the trunks the lower edge hangs this share of the depth higher than at
# the trunks: a draped, scalloped edge rather than a straight cut.
DRAPE = 0.3
# The sheet thins to nothing over this share of its depth above its lower edge: a rounded
# rim, full thickness above it.
EDGE = 0.15
# Sheets thinner than this many voxels (each side) fall between the lattice's samples and
# break into lace: the sheet ends there.
MIN_VOXELS = 0.75


@dataclass(frozen=True)
class Curtains:
    """Sheets of ice between close trunks.

    Attributes
    ----------
    balls : Balls
    area : float
        Area of the sheets outside the trunks (one side), square meters.
    pairs : int
        Pairs of trunks joined.
    """

    balls: Balls
    area: float
    pairs: int


NO_CURTAINS = Curtains(NO_BALLS, 0.0, 0)


def curtain_balls(traj: TrajectoryResult, surface: SurfaceParams, gravity) -> Curtains:
    """Sheets between icicle trunks closer than ``surface.curtain`` (meters; 0: none).

    Parameters
    ----------
    traj : TrajectoryResult
        Branch polylines, base to tip, in meters.
    surface : SurfaceParams
        ``params.resolve().surface``: ``curtain``, ``voxel_size`` and the profile (the
        trunks' radii).
    gravity : (3,) float

    Returns
    -------
    Curtains
    """
    distance = float(surface.curtain)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    trunks = np.flatnonzero((np.asarray(traj.branch_parent) < 0) & (np.diff(off) >= 2))
    if distance <= 0 or len(trunks) < 2:
        return NO_CURTAINS
    up = -unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    pts = np.asarray(traj.points, dtype=np.float64)
    x_pt, lengths = arc_lengths(traj.points, traj.branch_offsets)
    grown = grown_lengths(lengths, traj.cut)
    prof = profile_args(surface)
    growth = np.repeat(traj.growth(prof.growth), np.diff(off))
    radius = smooth_radius(x_pt, np.repeat(grown, np.diff(off)), replace(prof, growth=growth))
    bases = pts[off[trunks]]
    pairs = _neighbour_pairs(bases, distance)
    step = surface.voxel_size
    parts, area, joined = [], 0.0, 0
    for a, b in pairs:
        sheet = _sheet([_trunk(pts, radius, off, t, up) for t in (trunks[a], trunks[b])], distance, step)
        if sheet is not None:
            parts.append(sheet[0])
            area += sheet[1]
            joined += 1
    return Curtains(concat_balls(NO_BALLS, *parts), area, joined) if parts else NO_CURTAINS


def _neighbour_pairs(bases: np.ndarray, distance: float) -> np.ndarray:
    """Pairs of ``bases`` closer than ``distance`` with no third base in the sphere on
    their segment (the Gabriel graph): neighbours along an eave, not every pair in reach."""
    pairs = cKDTree(bases).query_pairs(distance, output_type="ndarray")
    if len(pairs) == 0:
        return pairs.reshape(0, 2)
    mid = 0.5 * (bases[pairs[:, 0]] + bases[pairs[:, 1]])
    half = 0.5 * np.linalg.norm(bases[pairs[:, 0]] - bases[pairs[:, 1]], axis=1)
    tree = cKDTree(bases)
    keep = [len(tree.query_ball_point(m, h * (1 - tol.slack))) == 0 for m, h in zip(mid, half)]
    return pairs[np.asarray(keep, dtype=bool)]


def _trunk(pts, radius, off, t, up):
    """A trunk as (heights ascending, points, radii) for interpolation at given heights;
    the heights never rise along the trunk (a bend saturates at ``max_tilt``), clamped so."""
    p, r = pts[off[t]:off[t + 1]], radius[off[t]:off[t + 1]]
    h = np.minimum.accumulate(p @ up)
    return h[::-1], p[::-1], r[::-1]


def _at(trunk, z):
    h, p, r = trunk
    return np.stack([np.interp(z, h, p[:, i]) for i in range(3)], axis=1), np.interp(z, h, r)


def _sheet(trunks, distance, step):
    """Balls of the sheet between two trunks and its area outside them; None for none."""
    (ha, _, _), (hb, _, _) = trunks
    top, bottom = min(ha[-1], hb[-1]), max(ha[0], hb[0])
    if top - bottom < 2 * step:
        return None
    z = top - step * np.arange(int((top - bottom) / step) + 1)
    (pa, ra), (pb, rb) = (_at(t, z) for t in trunks)
    gap = np.linalg.norm(pb - pa, axis=1)
    rows = int(np.cumprod(gap <= distance).sum())  # down to where the trunks part
    if rows < 2:
        return None
    z, pa, pb, ra, rb, gap = z[:rows], pa[:rows], pb[:rows], ra[:rows], rb[:rows], gap[:rows]
    depth = (top - z) / (top - bottom)
    count = np.maximum(np.ceil(gap / step).astype(np.int64), 1) + 1
    row = np.repeat(np.arange(rows), count)
    u = ragged_arange(count) / (count - 1)[row]
    reach = 1.0 - DRAPE * 4.0 * u * (1.0 - u)
    fade = np.sqrt(np.clip((reach - depth[row]) / EDGE, 0.0, 1.0))  # a rounded lower edge
    # At least half again what the lattice resolves, so the sheet ends at its draped edge
    # rather than where the thinner trunk's radius runs out.
    thickness = np.maximum(CURTAIN_SHARE * 0.5 * (ra + rb), 1.5 * MIN_VOXELS * step)[row] * fade
    keep = thickness >= MIN_VOXELS * step
    if not keep.any():
        return None
    cell = (gap / (count - 1))[row] * step  # area each ball stands for
    centres = pa[row] + u[:, None] * (pb - pa)[row]
    outside = (u * gap[row] > ra[row]) & ((1 - u) * gap[row] > rb[row])
    area = float(cell[keep & outside].sum())
    return sheet_balls(centres[keep], thickness[keep], cell[keep]), area
