"""The radius of an icicle along its trajectory, and points along branches."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...params import SurfaceParams
from ..trajectories import TrajectoryResult

# Ripples and noise fade out over this many tip radii above the tip, so the drop
# at the tip keeps the tip radius (Maeno's 2.44 mm) whatever the ripple phase.
TIP_CALM = 2.0
# Exponent of the physical profile r - tip ~ d^(3/4), d the distance from the tip: the
# similarity solution of a growing icicle (Short, Baygents & Goldstein, Phys. Fluids 18,
# 083101, 2006), confirmed on 93 lab icicles (Chen & Morris, Phys. Rev. E 83, 026307, 2011).
PHYSICAL_EXPONENT = 0.75
# An icicle the ground stopped goes on thickening as if it were longer by at most this
# many times its own length. Unlimited, the water of a 50 cm icicle on a 10 cm stub makes
# 6 cm milky pillars at lookdev; at 1, the bunny's chin icicles merge into one block.
GROUND_THICKENING = 0.5


@dataclass(frozen=True)
class Profile:
    """The smooth profile of an icicle and the ripple on it (`profile_radius`).

    Attributes
    ----------
    tip : float
        Tip radius, meters.
    growth : float or (k,) float
        ``t``, m/m: how much the base widens over the length (one value, or one per sample
        where each branch has its own).
    amplitude : float
        Ripple amplitude ``as``, meters.
    frequency : float
        Ripple frequency ``fs``, rad/m.
    shape : {"paper", "physical"}
        The cone of Equation 1 or the profile of real icicles.
    min_radius : float, optional
        Floor for the radius (ripples deeper than the icicle); default ``tip / 4``.
    """

    tip: float
    growth: float | np.ndarray
    amplitude: float = 0.0
    frequency: float = 0.0
    shape: str = "paper"
    min_radius: float | None = None


def profile_args(surface: SurfaceParams) -> Profile:
    """The `Profile` of a resolved ``surface`` group.

    The ripple amplitude is ``as * impurity``: ripples need dissolved salts, pure water
    grows smooth icicles (Chen & Morris, New J. Phys. 15, 2013).
    """
    return Profile(tip=surface.tip_radius, growth=surface.growth_ratio,
                   amplitude=surface.ripple_amplitude * surface.impurity, frequency=surface.ripple_frequency,
                   shape=surface.profile)


def profile_radius(x, length, profile: Profile):
    """Icicle radius along its trajectory, in meters.

    ``shape="paper"``, Equation 1: ``R(x) = tip + (L - x) t + as sin(x fs)``, a straight
    cone. ``shape="physical"``: ``R(x) = tip + t L^(1/4) d^(3/4) + as sin(x fs)`` with
    ``d = L - x`` the distance from the tip, the profile of real icicles; both reach
    ``tip + t L`` at the base, so ``t`` sets how much the base widens either way. The
    ripple fades to nothing over the last ``TIP_CALM`` tip radii so the tip keeps its
    radius.

    Parameters
    ----------
    x : (k,) float
        Arc length from the branch base (0) towards its tip, in meters.
    length : float or (k,) float
        Branch length L, in meters.
    profile : Profile
        ``tip`` (m), ``t`` (m/m), ``as`` (m), ``fs`` (rad/m), the shape and the floor.

    Returns
    -------
    (k,) float
        Radius in meters.
    """
    tip = profile.tip
    x = np.asarray(x, dtype=np.float64)
    length = np.asarray(length, dtype=np.float64)
    remaining = np.maximum(length - x, 0.0)
    calm = np.clip(remaining / (TIP_CALM * tip), 0.0, 1.0)
    r = tip + _widening(remaining, length, profile.growth, profile.shape) \
        + profile.amplitude * np.sin(x * profile.frequency) * calm
    return np.maximum(r, tip / 4 if profile.min_radius is None else profile.min_radius)


def smooth_radius(x, length, profile: Profile):
    """`profile_radius` without its ripple: the radius the ripple rides on (meters)."""
    x = np.asarray(x, dtype=np.float64)
    length = np.asarray(length, dtype=np.float64)
    return profile.tip + _widening(np.maximum(length - x, 0.0), length, profile.growth, profile.shape)


def ripple(x, length, tip, amplitude, frequency, phase=0.0):
    """The ripple term of `profile_radius`, faded near the tip (meters); ``phase`` (radians,
    scalar or per sample) shifts the wave along the branch."""
    x = np.asarray(x, dtype=np.float64)
    calm = np.clip(np.maximum(np.asarray(length, dtype=np.float64) - x, 0.0) / (TIP_CALM * tip), 0.0, 1.0)
    return amplitude * np.sin(x * frequency + phase) * calm


def _widening(d, length, growth, shape):
    if shape == "paper":
        return d * growth
    return growth * np.maximum(length, 0.0) ** (1 - PHYSICAL_EXPONENT) * d**PHYSICAL_EXPONENT


def grown_lengths(lengths: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """The length each branch's profile follows (meters): its own ``lengths`` (b,) plus what
    the ground ``cut`` (b,) from it (`TrajectoryResult.cut`), at most `GROUND_THICKENING`
    times its length."""
    lengths = np.asarray(lengths, dtype=np.float64)
    return lengths + np.minimum(np.asarray(cut, dtype=np.float64), GROUND_THICKENING * lengths)


def points_along(traj: TrajectoryResult, x_pt, lengths, branch, x):
    """Points at arc length ``x`` (k,) along branches ``branch`` (k,), with the unit direction
    of the polyline segment there; ``x_pt`` and ``lengths`` are `icefarm.geometry.arc_lengths`
    of ``traj``'s branches.

    Returns
    -------
    points, directions : (k, 3) float
    """
    pts = np.asarray(traj.points, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    counts = np.diff(off)
    # All branches laid end to end with a gap of 1 m: one monotone abscissa for np.interp.
    gap = np.concatenate([[0.0], np.cumsum(lengths + 1.0)[:-1]])
    xg = x_pt + np.repeat(gap, counts)
    tg = np.asarray(x, dtype=np.float64) + gap[branch]
    points = np.stack([np.interp(tg, xg, pts[:, a]) for a in range(3)], axis=1)
    lo, hi = off[branch], off[branch + 1] - 1
    seg = np.clip(np.searchsorted(xg, tg, side="right") - 1, lo, np.maximum(hi - 1, lo))
    d = pts[np.minimum(seg + 1, hi)] - pts[seg]
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return points, np.where(norm > 0, d / np.maximum(norm, 1e-300), [[0.0, -1.0, 0.0]])
