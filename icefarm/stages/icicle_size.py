"""How big an icicle the storm's water makes: its length from its ice volume through the
icicle profile, and its growth ratio (``storm.mode: physical``; `icefarm.stages.storm`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .rims import CAPTURE_POWER, CAPTURE_REACH, CAPTURE_ROUNDS, CAPTURE_SCALE, FUSE_MARGIN, HEAT_SPREAD, NUCLEUS_SPREAD
from .storm import GROWTH_MAX, WATER_TO_ICE, Constant, precipitation_m
from .surface.profile import smooth_radius

# An icicle freezes what the heat its surface loses allows (Makkonen 1988: its growth is
# limited by heat transfer; more water lowers lengthening, not thickening; the rest drips
# off the tip). Its surface freezes this many times the ice a level face's budget would
# (storm.freeze of the precipitation per area): a thin cylinder loses heat faster than a
# broad face, but its water film is warmed by all the water running over it. Chosen so a
# moderate freezing rain's longest icicles are about 0.4 m (light 0.2 m, severe 0.8 m);
# meltwater feeds icicles over nights of thaw and frost: 1.5 times the budget, at least a
# moderate storm's (light and moderate 0.6 m, severe 1.3 m).
ICICLE_HEAT = {"freezing_rain": 0.5, "meltwater": 0.75}
# An icicle its neighbours starved keeps at least this share of a fed one's thickening: the
# film's share it still gets, the rain on it and its freezing drop keep its base growing
# (real short icicles between long ones are carrots too, taper 3 and more).
STARVED_BASE = 0.7
# Past that limit the water's warmth slows the lengthening (Makkonen 1988; Maeno et al. 1994:
# more water, slower lengthening): an icicle fed x times what it can freeze reaches
# x^-WARM_WATER of the longest.
WARM_WATER = 0.25
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


def _bisect(below, lo: np.ndarray) -> np.ndarray:
    """``(k,)``: the least L >= ``lo`` where ``below(L)`` (a (k,) bool test, True up to one
    crossing) turns False, to 2^-50 of its bracket."""
    lo = np.array(lo, dtype=np.float64)
    hi = np.maximum(2.0 * lo, 1.0)
    while True:  # widen until every crossing is bracketed
        short = below(hi)
        if not short.any():
            break
        hi[short] *= 2.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        small = below(mid)
        lo = np.where(small, mid, lo)
        hi = np.where(small, hi, mid)
    return 0.5 * (lo + hi)


def length_from_volume(volume, tip: float, growth: float, shape: str = "physical",
                       thickening: float | None = None) -> np.ndarray:
    """``(k,)`` length in meters of icicles holding ``volume`` m^3 of ice (`icicle_volume`
    inverted by bisection: it rises monotonically with the length). With ``thickening``
    (meters) each icicle's growth ratio is `growth_ratios` of its length (at least
    ``growth``)."""
    volume = np.maximum(np.asarray(volume, dtype=np.float64).reshape(-1), 0.0)

    def held(L):
        return icicle_volume(L, tip, growth if thickening is None else growth_ratios(L, thickening, growth), shape)

    return _bisect(lambda L: held(L) < volume, np.zeros_like(volume))


def heat_limited_length(storm, surface, active=None, count: int = 1, exposure=None) -> np.ndarray:
    """``(k,)`` meters: the longest icicle the storm's cold can freeze, whatever its water.

    Its ice (`icicle_volume`) grows about as L^3 and the heat its surface loses over the
    storm (`icicle_area` times `ICICLE_HEAT` times a level face's budget, ``storm.freeze``
    of the precipitation) as L^2: past the length where they meet, more water drips off the
    tip instead of lengthening it. ``active`` (k,) thins the icicles its neighbours starved
    (`thickening_m`); ``exposure`` (k,) scales each one's share of the cold (`HEAT_SPREAD`).
    Stubs (the growth ratio above ``surface.growth_ratio``) are never limited."""
    share = np.ones(count) if active is None else np.asarray(active, dtype=np.float64).reshape(-1)
    # Freezing rain's cold comes with its rain; meltwater refreezes at the eave in the nights'
    # frost, for as many nights as the snow lasts: at least a moderate storm's budget.
    depth = precipitation_m(storm.intensity, storm.precipitation)
    if storm.kind == "meltwater":
        depth = max(depth, precipitation_m("moderate"))
    budget = ICICLE_HEAT[storm.kind] * storm.freeze * depth * WATER_TO_ICE
    if exposure is not None:
        budget = budget * np.asarray(exposure, dtype=np.float64).reshape(-1)
    thick = thickening_m(storm, share)
    tip, growth, shape = surface.tip_radius, surface.growth_ratio, surface.profile

    def within(L):
        t = growth_ratios(L, thick, growth)
        return icicle_volume(L, tip, t, shape) <= budget * icicle_area(L, tip, t, shape)

    stub = np.maximum(thick / max(growth, 1e-12), 1e-6)
    return np.where(within(stub), _bisect(within, stub), stub)


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


def icicle_lengths(volume, storm, surface, active=None, exposure=None) -> np.ndarray:
    """``(k,)`` meters: icicles from ``volume`` (k,) m^3 of water reaching their drip points.

    ``storm.icicle_share`` of it freezes on the icicle (the rest drips off its tip); the
    ice's volume gives the length through the icicle's profile (`length_from_volume` with
    ``surface.tip_radius`` and ``profile``; each icicle thickens `thickening_m`, for the share
    ``active`` (k,) of the storm it was fed), up to what the storm's cold can freeze
    (`heat_limited_length`, each with its ``exposure`` (k,) to the cold), and less the more
    water it was fed past that (`WARM_WATER`)."""
    ice = np.asarray(volume, dtype=np.float64).reshape(-1) * storm.icicle_share * WATER_TO_ICE
    fed = length_from_volume(ice, surface.tip_radius, surface.growth_ratio, surface.profile,
                             thickening=thickening_m(storm, active))
    cap = heat_limited_length(storm, surface, active, len(ice), exposure)
    thick = thickening_m(storm, active)
    frozen = icicle_volume(cap, surface.tip_radius, growth_ratios(cap, thick, surface.growth_ratio), surface.profile)
    excess = np.divide(ice, frozen, out=np.ones_like(ice), where=frozen > 0)
    # (meltwater's extra water is more nights of thaw, not a faster film: no warming)
    warm = WARM_WATER if storm.kind == "freezing_rain" else 0.0
    return np.where(fed > cap, cap * np.maximum(excess, 1.0) ** -warm, fed)


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
        radius = smooth_radius(below, length, self.surface.tip_radius, growth, shape=self.surface.profile)
        return np.where((below >= 0.0) & (below < length), radius, 0.0)


def constants() -> tuple[Constant, ...]:
    """The constants that size a storm's icicles and their fringe, for ``icefarm params``."""
    return (
        Constant("ICICLE_HEAT[freezing_rain]", ICICLE_HEAT["freezing_rain"], "-", "> 0",
                 "icicle surface's freezing over a level face's (heat-limited growth, Makkonen 1988; chosen: "
                 "longest 0.18 / 0.41 / 0.87 m light / moderate / severe)"),
        Constant("ICICLE_HEAT[meltwater]", ICICLE_HEAT["meltwater"], "-", "> 0",
                 "the same for meltwater, fed over nights of thaw and frost, at least a moderate storm's "
                 "budget (chosen: longest 0.62 m, severe 1.3 m)"),
        Constant("WARM_WATER", WARM_WATER, "-", ">= 0",
                 "freezing rain past the heat limit: length x (water / what freezes)^-this (more water, "
                 "slower lengthening: Makkonen 1988, Maeno et al. 1994)"),
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
