"""Ice where the water lands: mounds, stalagmites and columns under the icicles.

Each landing point (`icefarm.stages.landing`) gets a mound: a low cap of ice spread over
the surface it lies on, as wide as ``ground_ice.spread`` times its water and a quarter as
high. With ``ground_ice.mode: stalagmites`` a stalagmite rises from the mound towards the
tip above it: a metaball chain with the icicles' own calibration (`icicle_balls`), but
blunter (a top `STALAGMITE_TOP` times the icicle's tip radius, a base that widens by
``ground_ice.width`` per meter of height) and lumpy (its axis wanders, `STALAGMITE_LUMPS`),
``ground_ice.height_scale`` times its water high, never past the tip. One that would reach the tip does: it ends
in the icicle's drop, and the two fuse into a column. All of it is balls of the icicles' field, so it fuses
with them into the one watertight mesh.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ...geometry import perpendicular_basis, ragged_arange, unit
from ...metaballs.balls import NO_BALLS, Balls, concat_balls, sheet_balls
from ...params import GroundIceParams, SurfaceParams
from ..landing import LandingResult
from ..trajectories import TrajectoryResult
from .icicles import icicle_balls

# Mound height over its radius: a low cap, as drops that splash and spread before they freeze.
MOUND_FLATNESS = 0.25
# Most balls in one mound (a Vogel spiral); about a dozen overlap at each point of its sheet.
MOUND_BALLS = 256
# A mound stays on the surface it started on: disc points whose surface lies more than this
# many mound radii above or below the landing point (past a ledge's edge) get no ice.
MOUND_STEP = 0.5
# Top radius of a stalagmite, in icicle tip radii: splashing drops round it off into a blunt
# dome, far wider than the pendant drop that shapes an icicle's tip (2 read as glass pyramids).
STALAGMITE_TOP = 4.0
# Its axis wanders sideways by this many top radii (standard deviation) every two top radii
# of height: splash freezes in lumps, not a straight cone.
STALAGMITE_LUMPS = 0.3
# A stalagmite whose top would come within this many top radii of the tip above it grows
# into it: a column.
COLUMN_REACH = 1.0
_GOLDEN = math.pi * (3.0 - math.sqrt(5.0))


@dataclass(frozen=True)
class GroundIce:
    """The ice that grows where the water lands, as metaballs, with its measures.

    Attributes
    ----------
    balls : Balls
        Mounds and stalagmites, for the icicles' field.
    heights : (k,) float
        Height of each landing point's stalagmite along -gravity, meters (the gap to the
        tip for a column; 0 without a stalagmite).
    columns : (k,) bool
        Stalagmites that reach their tip.
    mound_radius : (k,) float
        Radius of each mound, meters (0: too little water for the lattice to show one).
    """

    balls: Balls
    heights: np.ndarray
    columns: np.ndarray
    mound_radius: np.ndarray


def ground_ice_balls(landing: LandingResult, ground_ice: GroundIceParams,
                     surface: SurfaceParams, gravity, rng: np.random.Generator, *, cast=None,
                     floor: float | None = None) -> GroundIce:
    """Mounds (and stalagmites) of ice at each landing point.

    Parameters
    ----------
    landing : LandingResult
    ground_ice : GroundIceParams
        ``params.resolve().ground_ice``: ``mode`` (none, mounds, stalagmites),
        ``spread`` (mound radius per meter of water, m/m), ``height_scale`` (stalagmite
        height per meter of water, m/m), ``width`` (stalagmite base radius per meter of
        height, m/m).
    surface : SurfaceParams
        ``params.resolve().surface``: the tip radius, profile, noise and voxel size.
    gravity : (3,) float
    rng : numpy.random.Generator
        The stalagmites' noise (``surface.noise``).
    cast : callable, optional
        `icefarm.spatial.ray_caster` of the object: mounds follow its surface.
    floor : float, optional
        Height of the ground plane along -gravity; None: no ground.

    Returns
    -------
    GroundIce
    """
    k = len(landing)
    zero = np.zeros(k)
    if ground_ice.mode == "none" or k == 0:
        return GroundIce(NO_BALLS, zero, np.zeros(k, dtype=bool), zero)
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    voxel = surface.voxel_size
    radius = ground_ice.spread * landing.water
    radius = np.where(radius > 2 * voxel, radius, 0.0)  # a drop or two: nothing the lattice shows
    mounds = [_mound(landing.positions[i], landing.normals[i], radius[i], max(MOUND_FLATNESS * radius[i], voxel),
                     voxel, g, cast, floor) for i in np.flatnonzero(radius)]
    if ground_ice.mode != "stalagmites":
        return GroundIce(concat_balls(NO_BALLS, *mounds), zero, np.zeros(k, dtype=bool), radius)
    stalagmites, heights, columns = _stalagmites(landing, ground_ice, surface, g, rng)
    return GroundIce(concat_balls(NO_BALLS, *mounds, stalagmites), heights, columns, radius)


def _mound(centre, normal, radius, height, voxel, g, cast, floor) -> Balls:
    """A cap ``height (1 - (d / radius)^2)^2`` thick over the surface around ``centre``.

    Points of a Vogel spiral on the disc in the tangent plane are dropped along gravity onto
    the object (``cast``) or the ground, so the cap follows a curved basin or a step; a
    point whose surface lies `MOUND_STEP` radii off the landing point's height gets none.
    """
    spacing = max(height / 2, voxel)
    n = int(np.clip(math.pi * (radius / spacing) ** 2, 7, MOUND_BALLS))
    j = np.arange(n)
    rho = radius * np.sqrt((j + 0.5) / n)
    e1, e2 = perpendicular_basis(normal)
    disc = centre + rho[:, None] * (np.cos(j * _GOLDEN)[:, None] * e1 + np.sin(j * _GOLDEN)[:, None] * e2)
    up = -g
    lift = MOUND_STEP * radius
    start = disc + ((centre - disc) @ up + lift)[:, None] * up  # all at the landing height, lifted
    fall = np.full(n, np.inf)
    if cast is not None:
        fall, _ = cast(start, np.tile(g, (n, 1)))
    if floor is not None:
        fall = np.minimum(fall, np.maximum(start @ up - floor, 0.0))
    ok = fall <= 2 * lift
    if not ok.any():
        return NO_BALLS
    points = start[ok] + fall[ok, None] * g
    thickness = height * (1.0 - (rho[ok] / radius) ** 2) ** 2
    return sheet_balls(points, thickness, math.pi * radius**2 / n)


def _stalagmites(landing: LandingResult, ground_ice: GroundIceParams, surface: SurfaceParams, g: np.ndarray,
                 rng: np.random.Generator):
    """Chains from each landing point up towards its tip; see `ground_ice_balls`.

    Returns
    -------
    balls : Balls
    heights : (k,) float
    columns : (k,) bool
    """
    tip = surface.tip_radius
    top = STALAGMITE_TOP * tip
    up = -g
    want = ground_ice.height_scale * landing.water
    gaps = landing.gaps
    # Under a tip closer than a stalagmite's rounded top (an icicle the ground stopped
    # stands in its own foot) there is no room for one: the mound alone spreads there.
    room = gaps >= 2 * top
    columns = room & (want >= gaps - COLUMN_REACH * top)
    heights = np.where(columns, gaps, np.where(room & (want >= 2 * top), want, 0.0))
    grow = heights > 0
    axis = landing.tips - landing.positions
    rise = axis @ up
    # A chain's last ball is the centre of its rounded top: a column's is the icicle's tip,
    # a free stalagmite's lies a top radius under the height it reaches.
    reach = np.where(columns, 1.0, (heights - top) / np.maximum(rise, 1e-12))
    ends = landing.positions + np.clip(reach, 0.0, 1.0)[:, None] * axis
    idx = np.flatnonzero(grow)
    if len(idx) == 0:
        return NO_BALLS, heights, columns
    # A lumpy axis: points every two top radii, moved sideways at random (not the ends).
    count = np.maximum(np.ceil((heights[idx] - top) / (2 * top)).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(len(idx)), count)
    k = ragged_arange(count)
    t = (k / (count - 1)[owner])[:, None]
    points = landing.positions[idx][owner] * (1 - t) + ends[idx][owner] * t
    inner = (k > 0) & (k < count[owner] - 1)
    if inner.any():
        side = rng.normal(scale=STALAGMITE_LUMPS * top, size=(int(inner.sum()), 3))
        points[inner] += side - (side @ up)[:, None] * up
    traj = TrajectoryResult(points=points, branch_offsets=np.r_[0, np.cumsum(count)],
                            branch_icicle=np.arange(len(idx)), branch_parent=np.full(len(idx), -1))
    # The icicles' chain with a blunt top and a wide base: R = top + width L^1/4 d^3/4.
    shape = dataclasses.replace(surface, tip_radius=top, growth_ratio=ground_ice.width, profile="physical")
    return icicle_balls(traj, shape, rng), heights, columns
