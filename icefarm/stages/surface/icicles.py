"""Metaball chains along every icicle branch (paper 4.4.1-4.4.2)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...geometry import arc_lengths, ragged_arange
from ...metaballs.balls import KAPPA, LEVEL, NO_BALLS, SPACING, TIP_WEIGHT, Balls
from ...params import SurfaceParams
from ...tol import tol
from ..trajectories import TrajectoryResult
from .profile import TIP_CALM, grown_lengths, points_along, profile_args, smooth_radius

# The blended end of a wide chain bulges a little past its last ball's radius (0.15 mm on
# a 0.3 m sphere's icicles): the foot's chain stops this many tip radii shorter still.
FOOT_CLEARANCE = 0.1


def icicle_balls(traj: TrajectoryResult, surface: SurfaceParams, rng: np.random.Generator) -> Balls:
    """Metaball chains along every branch (paper 4.4.1-4.4.2).

    Balls are spaced ``SPACING * KAPPA * R(x)`` apart along each branch, from its base
    (x = 0) to exactly its tip (x = L), R the profile without its ripple (a chain of balls
    that wide blurs centimetre ripples away: `icefarm.stages.surface.ripples` carves them
    into the mesh instead); each is moved at random within ``noise`` in the plane
    perpendicular to the branch (uniform over the disk), except near the tip.

    Returns
    -------
    Balls
    """
    prof = profile_args(surface)
    tip = prof.tip
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if len(branches) == 0:
        return NO_BALLS
    x_pt, all_lengths = arc_lengths(traj.points, traj.branch_offsets)
    grown = grown_lengths(all_lengths[branches], traj.cut[branches])
    growth = traj.growth(prof.growth)[branches]  # per branch under a physical storm
    # A cut branch ends on the ground in a foot wider than the tip's drop: its chain stops
    # short by the difference, so the foot rests on the ground instead of sinking into it.
    per_branch = dataclasses.replace(prof, growth=growth)
    foot = smooth_radius(all_lengths[branches], grown, per_branch) - tip + FOOT_CLEARANCE * tip
    if traj.branch_growth is not None:  # a storm's stub widens fast above its end: the foot is wider there
        for _ in range(3):
            foot = smooth_radius(np.maximum(all_lengths[branches] - foot, 0.0), grown, per_branch) \
                - tip + FOOT_CLEARANCE * tip
    lengths = np.where(traj.cut[branches] > 0, np.maximum(all_lengths[branches] - foot, 0.0), all_lengths[branches])
    nb = len(branches)

    # Fine samples of each branch to integrate u(x) = int dx / h(x): balls sit at equal steps of u.
    step_min = SPACING * KAPPA * tip / 4
    nfine = np.maximum(np.ceil(lengths / step_min).astype(np.int64), 1) + 1
    fb = np.repeat(np.arange(nb), nfine)
    fstart = np.cumsum(nfine) - nfine
    fj = ragged_arange(nfine)
    fx = fj * (lengths / (nfine - 1))[fb]
    fr = smooth_radius(fx, grown[fb], dataclasses.replace(prof, growth=growth[fb]))
    inv_h = 1.0 / (SPACING * KAPPA * fr)
    du = np.zeros_like(fx)
    du[1:] = 0.5 * (inv_h[1:] + inv_h[:-1]) * np.diff(fx)
    du[fstart] = 0.0
    u = np.cumsum(du)
    u_len = u[fstart + nfine - 1] - u[fstart]
    nint = np.ceil(u_len - tol.slack).astype(np.int64)  # intervals between balls; 0: one lone ball
    nballs = nint + 1
    bb = np.repeat(np.arange(nb), nballs)
    bk = ragged_arange(nballs)
    # Global monotone u with a gap of 1 between branches, so np.interp never mixes branches.
    gap = np.arange(nb, dtype=np.float64)
    ug = u + gap[fb]
    target = (u[fstart] + gap)[bb] + bk * np.where(nint > 0, u_len / np.maximum(nint, 1), 0.0)[bb]
    bx = np.interp(target, ug, fx)
    bx[bk == nint[bb]] = lengths[bb][bk == nint[bb]]  # the last ball exactly at the tip
    radius = smooth_radius(bx, grown[bb], dataclasses.replace(prof, growth=growth[bb]))

    pos, tangent = points_along(traj, x_pt, all_lengths, branches[bb], bx)

    noise = surface.noise
    if noise > 0:
        e1, e2 = perpendicular_frame(tangent)
        calm = np.clip((grown[bb] - bx) / (TIP_CALM * tip), 0.0, 1.0)
        rad = noise * np.sqrt(rng.random(len(bx))) * calm
        ang = rng.random(len(bx)) * (2 * math.pi)
        pos = pos + rad[:, None] * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)

    # Weights: a chain packed tighter than SPACING weighs proportionally less; the tip
    # ball weighs TIP_WEIGHT more to round the end; a lone ball is a sphere of radius R.
    weight = np.where(nint > 0, u_len / np.maximum(nint, 1), 1.0)[bb]
    weight = np.where(bk == nint[bb], weight * TIP_WEIGHT, weight)
    lone = (nint == 0)[bb]
    weight[lone] = LEVEL * math.exp(1.0 / KAPPA**2)
    return Balls(pos, KAPPA * radius, weight)


def perpendicular_frame(tangent: np.ndarray):
    """Two unit vectors perpendicular to each unit ``tangent`` (k, 3) and to each other."""
    helper = np.where(np.abs(tangent[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(tangent, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(tangent, e1)



# A drip point whose face leans at least this much off horizontal (sine of the angle between
# its normal and gravity) sits on or near a rim: its icicle's root moves in under the object.
ROOT_LEAN = 0.2


def root_shifts(normals: np.ndarray, gravity: np.ndarray, thickness: np.ndarray) -> np.ndarray:
    """``(k, 3)`` where each icicle's root goes so that it hangs from the object rather than
    standing proud of it, meters: horizontally into the object (away from the face its drip
    point's normal leans towards), as far as ``thickness`` (k,) allows; zero under a face
    that looks down (the ball's top is inside the object there already), or where the
    thickness is not finite.

    A ball centred on an eave's rim puts a glass dome in front of the fascia, above the edge;
    moved in by its radius, its front is flush with the fascia and its top inside the eave.
    """
    g = np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity)
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    across = n - (n @ g)[:, None] * g
    lean = np.linalg.norm(across, axis=1)
    inward = -across / np.maximum(lean, 1e-300)[:, None]
    # a ray that never left (an open mesh) says nothing of how thick it is there: no move
    room = np.asarray(thickness, dtype=np.float64)
    room = np.where(np.isfinite(room), room, 0.0)
    return np.where((lean >= ROOT_LEAN)[:, None], inward * room[:, None], 0.0)


def hang_roots(traj: TrajectoryResult, surface: SurfaceParams, shift: np.ndarray) -> TrajectoryResult:
    """The trajectories with each trunk's points within their radius of the drip point moved
    along ``shift`` (icicles, 3) by ``R(x) - x``, at most its length: the axes stage 4 builds
    and measures the ice on (stage 3's own stay as they are).

    Only trunks move; a branch keeps its points (it leaves the trunk below its root).
    """
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    counts = np.diff(off)
    if len(traj.points) == 0:
        return traj
    prof = profile_args(surface)
    x, lengths = arc_lengths(traj.points, off)
    grown = grown_lengths(lengths, traj.cut)
    growth = traj.growth(prof.growth)
    owner = np.repeat(np.arange(len(counts)), counts)
    radius = smooth_radius(x, grown[owner], dataclasses.replace(prof, growth=growth[owner]))
    move = np.asarray(shift, dtype=np.float64)[np.asarray(traj.branch_icicle)[owner]]
    reach = np.linalg.norm(move, axis=1)
    trunk = np.asarray(traj.branch_parent)[owner] < 0
    step = np.where(trunk, np.minimum(np.maximum(radius - x, 0.0), reach), 0.0)
    if not step.any():
        return traj
    points = traj.points + (step / np.maximum(reach, 1e-300))[:, None] * move
    return dataclasses.replace(traj, points=points)
