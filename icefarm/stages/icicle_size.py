"""How big an icicle the storm's water makes: its length from its ice volume through the
icicle profile, and its growth ratio (``storm.mode: physical``; `icefarm.stages.storm`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .rims import CAPTURE_POWER, CAPTURE_REACH, CAPTURE_ROUNDS, CAPTURE_SCALE, FUSE_MARGIN, HEAT_SPREAD, NUCLEUS_SPREAD
from .storm import GROWTH_MAX, WATER_TO_ICE, Constant, precipitation_m
from .surface.profile import Profile, smooth_radius

# An icicle's surface freezes this many times the ice a level face's budget would per area
# (storm.freeze of the precipitation): a thin cylinder loses heat faster than a broad face (a
# 1 cm rod in a 3 m/s wind about 50 W/m^2K by Hilpert's correlation, a 0.5 m plate about 10
# by the laminar flat plate's: Incropera, Fundamentals of Heat and Mass Transfer), less the
# warmth of the film running over it. Chosen in that range so a moderate freezing rain's
# longest icicles are about 0.4 m (light 0.2 m, severe 0.8 m); meltwater feeds icicles over
# nights of thaw and frost: 1.5 times the budget, at least a moderate storm's (0.6 m, severe
# 1.3 m).
ICICLE_HEAT = {"freezing_rain": 1.6, "meltwater": 2.4}
# An icicle starts as the drop hanging from its drip point: this many tip radii long.
NUCLEUS_TIPS = 2.0
# Lengths the growth is tabulated on, meters: log-spaced from the nucleus to this, in this
# many steps (3 % apart, well within a mesh's detail).
LONGEST_M = 16.0
GROWTH_STEPS = 256
# An icicle its neighbours starved keeps at least this share of a fed one's thickening: the
# film's share it still gets, the rain on it and its freezing drop keep its base growing
# (real short icicles between long ones are carrots too, taper 3 and more).
STARVED_BASE = 0.7
# Fed faster than it can freeze, the water's warmth slows the lengthening (Makkonen 1988;
# Maeno et al. 1994: more water, slower lengthening): an icicle fed x times what its surface
# freezes at the storm's end is x^-WARM_WATER as long (freezing rain; chosen).
WARM_WATER = 0.35
# A side branch of a storm's icicle takes part of its water and grows for this share of the
# generations left when it splits off: it ends above the trunk's tip (1, the paper's, ends
# every branch beside it: three or four equal fingers read as a claw). Chosen, by eye.
BRANCH_LIFE = 0.5


def icicle_volume(length, tip: float, growth, shape: str = "physical"):
    """Volume of an icicle of ``length`` meters (array-like), m^3: the solid of its profile.

    ``physical``: ``r = tip + t L^(1/4) d^(3/4)`` gives ``pi (tip^2 L + 8/7 tip t L^2 + 2/5 t^2 L^3)``;
    ``paper``: ``r = tip + t d`` gives ``pi (tip^2 L + tip t L^2 + t^2 L^3 / 3)``. ``growth`` t
    may be an array like ``length``.
    """
    L = np.asarray(length, dtype=np.float64)
    t = np.asarray(growth, dtype=np.float64)
    if shape == "physical":
        return math.pi * (tip * tip * L + 8.0 / 7.0 * tip * t * L ** 2 + 0.4 * t ** 2 * L ** 3)
    return math.pi * (tip * tip * L + tip * t * L ** 2 + t ** 2 * L ** 3 / 3.0)


def growth_ratios(length, thickening: float, growth: float) -> np.ndarray:
    """``(k,)`` growth ratio t of icicles ``length`` meters long whose base thickened at least
    ``thickening`` meters: ``thickening / L``, at least ``growth`` (a long icicle's, the
    widening measured on real ones) and at most `GROWTH_MAX`."""
    L = np.maximum(np.asarray(length, dtype=np.float64), 1e-9)
    return np.clip(thickening / L, growth, max(growth, GROWTH_MAX))


def icicle_area(length, tip: float, growth, shape: str = "physical"):
    """Lateral area of an icicle of ``length`` meters (array-like), m^2: ``2 pi`` times the
    integral of its profile's radius, ``2 pi (tip L + 4/7 t L^2)`` (``physical``) or
    ``2 pi (tip L + t L^2 / 2)`` (``paper``)."""
    L = np.asarray(length, dtype=np.float64)
    t = np.asarray(growth, dtype=np.float64)
    return 2.0 * math.pi * (tip * L + (4.0 / 7.0 if shape == "physical" else 0.5) * t * L * L)


def thickening_m(storm, active=None):
    """Meters an icicle's base thickens at least over the storm: the radial ice of a bar that
    freezes ``storm.freeze`` of its rain, ``freeze P rho_w / (pi rho_i)`` (Jones 1998).
    Thickening is set by the heat the icicle loses more than by its water (Makkonen 1988:
    more water lowers lengthening, not thickening), so a short icicle is a stubby cone, not a
    straw; a long one widens by ``surface.growth_ratio`` of its length, as real ones do.
    ``active`` ((k,), 0 to 1): the share of the storm each icicle was fed; one its neighbours
    starved thickens less, down to `STARVED_BASE` of it (a float without it, a (k,) array
    with it)."""
    full = storm.freeze * precipitation_m(storm.intensity, storm.precipitation) * WATER_TO_ICE / math.pi
    if active is None:
        return full
    return full * (STARVED_BASE + (1.0 - STARVED_BASE) * np.asarray(active, dtype=np.float64))


def _interp_rows(y, table_y, table_x) -> np.ndarray:
    """``(k,)``: in each row of ``table_y`` (k, m), increasing along the row, where it reaches
    ``y`` (k,), read off ``table_x`` (k, m) linearly (clamped to the row's ends)."""
    rows = np.arange(len(y))
    j = np.clip((table_y < y[:, None]).sum(axis=1), 1, table_y.shape[1] - 1)
    y0, y1 = table_y[rows, j - 1], table_y[rows, j]
    f = np.clip((y - y0) / np.where(y1 > y0, y1 - y0, 1.0), 0.0, 1.0)
    return table_x[rows, j - 1] + f * (table_x[rows, j] - table_x[rows, j - 1])


@dataclass(frozen=True)
class IcicleGrowth:
    """Icicles grown over a storm by `grow_icicles`.

    Attributes
    ----------
    length : (k,) float
        Meters.
    share : (k,) float
        The share of its water each one froze; the rest dripped off its tip.
    """

    length: np.ndarray
    share: np.ndarray


def grow_icicles(volume, storm, surface, active=None, exposure=None, slowed: bool = True) -> IcicleGrowth:
    """Grow icicles fed ``volume`` (k,) m^3 of water, evenly over the storm.

    Each freezes what reaches it or what the heat its surface loses freezes, whichever is
    less (the heat and mass balance of Makkonen 1988, integrated over the growth as Szilder &
    Lozowski 1994 do); the rest drips off its tip. Its surface loses ``ICICLE_HEAT`` times a
    level face's budget (``storm.freeze`` of the precipitation) per area over the storm, so a
    young icicle, a drop `NUCLEUS_TIPS` tip radii long, drips most of a steady film, and a
    grown one freezes all of it: the share frozen follows from the water and the cold, and
    with plenty of water the length is the cold's (its ice grows as L^3, its surface as L^2:
    about linearly in time). Its ice fills the icicle profile (`icicle_volume` with
    ``surface.tip_radius``, ``growth_ratio`` and ``profile``), its base thickening
    `thickening_m` for the share ``active`` (k,) of the storm it was fed; ``exposure`` (k,)
    scales its share of the cold. In freezing rain an icicle fed x times what it freezes at
    the end is x^-`WARM_WATER` as long (``slowed``).
    """
    ice = np.asarray(volume, dtype=np.float64).reshape(-1) * WATER_TO_ICE
    k = len(ice)
    fed = np.ones(k) if active is None else np.asarray(active, dtype=np.float64).reshape(-1)
    # Freezing rain's cold comes with its rain; meltwater refreezes at the eave in the nights'
    # frost, for as many nights as the snow lasts: at least a moderate storm's budget.
    depth = precipitation_m(storm.intensity, storm.precipitation)
    if storm.kind == "meltwater":
        depth = max(depth, precipitation_m("moderate"))
    cold = np.full(k, ICICLE_HEAT[storm.kind] * storm.freeze * depth * WATER_TO_ICE)
    if exposure is not None:
        cold = cold * np.asarray(exposure, dtype=np.float64).reshape(-1)
    cold = np.maximum(cold, 1e-30)
    tip, shape = surface.tip_radius, surface.profile
    lengths = np.concatenate([[0.0], np.geomspace(NUCLEUS_TIPS * tip, LONGEST_M, GROWTH_STEPS)])
    L = np.broadcast_to(lengths, (k, len(lengths)))
    t = growth_ratios(L, np.broadcast_to(thickening_m(storm, fed), (k,))[:, None], surface.growth_ratio)
    held = icicle_volume(L, tip, t, shape)
    freezes = cold[:, None] * icicle_area(L, tip, t, shape)  # m^3 of ice per storm, at each length
    # time (in storms) to grow each length while the cold limits it: dt = dV / (cold A)
    step = np.diff(held, axis=1) / (0.5 * (freezes[:, 1:] + freezes[:, :-1]))
    step[:, 0] = 0.0  # the first drop hangs from the start
    when = np.concatenate([np.zeros((k, 1)), np.cumsum(step, axis=1)], axis=1)
    # the cold limits it until its surface freezes the water as fast as it comes
    turn = _interp_rows(ice, freezes, L)
    turned = _interp_rows(turn, L, when)
    frozen = np.where(turned >= 1.0, _interp_rows(np.ones(k), when, held),
                      _interp_rows(turn, L, held) + ice * (1.0 - turned))
    frozen = np.minimum(frozen, ice)
    length = _interp_rows(frozen, held, L)
    if slowed and storm.kind == "freezing_rain":  # meltwater's extra water is more nights of thaw, not a faster film
        excess = ice / np.maximum(_interp_rows(length, L, freezes), 1e-30)
        length = length * np.maximum(excess, 1.0) ** -WARM_WATER
    share = np.divide(frozen, ice, out=np.ones(k), where=ice > 0)
    return IcicleGrowth(length=np.where(ice > 0, length, 0.0), share=share)


def icicle_lengths(volume, storm, surface, active=None, exposure=None) -> np.ndarray:
    """``(k,)`` meters: the length of `grow_icicles` fed ``volume`` (k,) m^3 of water."""
    return grow_icicles(volume, storm, surface, active, exposure).length


def heat_limited_length(storm, surface, active=None, count: int = 1, exposure=None) -> np.ndarray:
    """``(k,)`` meters: the longest icicle the storm's cold grows, with all the water it can
    take (`grow_icicles` without `WARM_WATER`'s slowing). ``active`` (k,) thins the icicles
    its neighbours starved (`thickening_m`); ``exposure`` (k,) scales each one's share of
    the cold."""
    plenty = np.full(count if active is None else len(np.atleast_1d(active)), 1e6)
    return grow_icicles(plenty, storm, surface, active, exposure, slowed=False).length


@dataclass(frozen=True)
class IcicleSizing:
    """How a storm's water sizes its icicles: `icicle_lengths` and their profile's radius,
    for stage 2 to weigh which icicles fuse (`icefarm.stages.rims.swallow`).

    Attributes
    ----------
    storm, surface : StormParams, SurfaceParams
    branch_reach : float
        How far aside a long icicle's side branches hang (``trajectories.branch_spread``
        where icicles branch), meters: a neighbour that close to it fuses with them.
    """

    storm: Any
    surface: Any
    branch_reach: float = 0.0

    def length(self, volume, active=None, exposure=None) -> np.ndarray:
        """``(k,)`` meters: `icicle_lengths` of ``volume`` (k,) m^3 of water."""
        return icicle_lengths(volume, self.storm, self.surface, active, exposure)

    def radius(self, length, active, depth) -> np.ndarray:
        """``(k,)`` meters: the smooth radius of icicles ``length`` (k,) long, fed ``active``
        (k,) of the storm, ``depth`` (k,) meters below their roots (0 above the roots and past
        the tips)."""
        length = np.asarray(length, dtype=np.float64)
        growth = growth_ratios(length, thickening_m(self.storm, active), self.surface.growth_ratio)
        below = np.asarray(depth, dtype=np.float64)
        radius = smooth_radius(below, length, Profile(self.surface.tip_radius, growth, shape=self.surface.profile))
        return np.where((below >= 0.0) & (below < length), radius, 0.0)


def constants() -> tuple[Constant, ...]:
    """The constants that size a storm's icicles and their fringe, for ``icefarm params``."""
    return (
        Constant("ICICLE_HEAT[freezing_rain]", ICICLE_HEAT["freezing_rain"], "-", "> 0",
                 "an icicle surface's freezing per area over a level face's: a thin rod loses heat faster "
                 "(Hilpert's cylinder vs the flat plate's, Incropera: 1-5); its growth integrated over the storm, "
                 "freezing what reaches it or what its cold allows, the rest dripping (Makkonen 1988; Szilder & "
                 "Lozowski 1994). Chosen: longest 0.19 / 0.40 / 0.84 m light / moderate / severe"),
        Constant("ICICLE_HEAT[meltwater]", ICICLE_HEAT["meltwater"], "-", "> 0",
                 "the same for meltwater, fed over nights of thaw and frost, at least a moderate storm's "
                 "budget (chosen: longest 0.64 m, severe 1.3 m)"),
        Constant("NUCLEUS_TIPS", NUCLEUS_TIPS, "tip radii", "> 0",
                 "an icicle starts as a drop this long: young icicles drip most of a steady film"),
        Constant("WARM_WATER", WARM_WATER, "-", ">= 0",
                 "freezing rain fed x times what an icicle freezes at the end: length x x^-this (more water, "
                 "slower lengthening: Makkonen 1988, Maeno et al. 1994; chosen)"),
        Constant("HEAT_SPREAD", HEAT_SPREAD, "-", ">= 0",
                 "each icicle's share of the cold: min(1, log-normal of this sigma): a later start, shelter (chosen)"),
        Constant("BRANCH_LIFE", BRANCH_LIFE, "-", "]0, 1]",
                 "a side branch grows for this share of its icicle's generations left (chosen: no claws)"),
        Constant("STARVED_BASE", STARVED_BASE, "-", "[0, 1]",
                 "a starved icicle's least share of the base's thickening"),
        Constant("CAPTURE_ROUNDS", CAPTURE_ROUNDS, "-", ">= 1",
                 "rounds of the icicles' competition for the rim's film"),
        Constant("CAPTURE_REACH", CAPTURE_REACH, "spacing", "> 0", "how far an icicle draws the film from"),
        Constant("CAPTURE_SCALE", CAPTURE_SCALE, "spacing", "> 0", "Gaussian scale of its pull"),
        Constant("CAPTURE_POWER", CAPTURE_POWER, "-", ">= 0", "its pull grows as its ice to this power"),
        Constant("NUCLEUS_SPREAD", NUCLEUS_SPREAD, "-", ">= 0", "how much the first drops differ (log-normal sigma)"),
        Constant("FUSE_MARGIN", FUSE_MARGIN, "m", ">= 0",
                 "closer at half length, a drip point feeds the bigger icicle (the metaball field fuses them)"),
    )
