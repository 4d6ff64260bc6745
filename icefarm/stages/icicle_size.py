"""How big an icicle the storm's water makes: its length from its ice volume through the
icicle profile, and its growth ratio (``storm.mode: physical``; `icefarm.stages.storm`)."""

from __future__ import annotations

import math

import numpy as np

from .storm import GROWTH_MAX, WATER_TO_ICE, precipitation_m


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


def length_from_volume(volume, tip: float, growth: float, shape: str = "physical",
                       thickening: float | None = None) -> np.ndarray:
    """``(k,)`` length in meters of icicles holding ``volume`` m^3 of ice (`icicle_volume`
    inverted by bisection: it rises monotonically with the length). With ``thickening``
    (meters) each icicle's growth ratio is `growth_ratios` of its length (at least
    ``growth``)."""
    volume = np.maximum(np.asarray(volume, dtype=np.float64).reshape(-1), 0.0)

    def held(L):
        return icicle_volume(L, tip, growth if thickening is None else growth_ratios(L, thickening, growth), shape)

    lo = np.zeros_like(volume)
    hi = np.full_like(volume, 1.0)
    while True:  # widen until every volume is bracketed
        short = held(hi) < volume
        if not short.any():
            break
        hi[short] *= 2.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        small = held(mid) < volume
        lo = np.where(small, mid, lo)
        hi = np.where(small, hi, mid)
    return 0.5 * (lo + hi)


def thickening_m(storm) -> float:
    """Meters an icicle's base thickens at least over the storm: the radial ice of a bar that
    freezes ``storm.freeze`` of its rain, ``freeze P rho_w / (pi rho_i)`` (Jones 1998).
    Thickening is set by the heat the icicle loses more than by its water (Makkonen 1988:
    more water lowers lengthening, not thickening), so a short icicle is a stubby cone, not a
    straw; a long one widens by ``surface.growth_ratio`` of its length, as real ones do."""
    return storm.freeze * precipitation_m(storm.intensity, storm.precipitation) * WATER_TO_ICE / math.pi


def icicle_lengths(volume, storm, surface) -> np.ndarray:
    """``(k,)`` meters: icicles from ``volume`` (k,) m^3 of water reaching their drip points.

    ``storm.icicle_share`` of it freezes on the icicle (the rest drips off its tip); the
    ice's volume gives the length through the icicle's profile (`length_from_volume` with
    ``surface.tip_radius`` and ``profile``; each icicle thickens `thickening_m`)."""
    ice = np.asarray(volume, dtype=np.float64) * storm.icicle_share * WATER_TO_ICE
    return length_from_volume(ice, surface.tip_radius, surface.growth_ratio, surface.profile,
                              thickening=thickening_m(storm))
