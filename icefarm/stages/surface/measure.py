"""Physical plausibility of the icicles, measured on the ice mesh."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ...geometry import arc_lengths, ragged_arange, within_box
from ...params import SurfaceParams
from ...spatial import nearest, point_index
from ..trajectories import TrajectoryResult
from ..trajectory_stats import SHAPE_MIN_LENGTH
from .crossings_kernel import edge_crossings
from .profile import grown_lengths, points_along

# Radius samples along a trunk: from TAPER_AT of its length below its base to FIT_END; the
# profile is fitted between FIT_START and FIT_END of the distance from the tip, clear of the
# drop at the tip and of the base ice around the drip point.
TAPER_AT = 0.1
FIT_START, FIT_END = 0.15, 0.85
# A ripple whose fitted amplitude stays under this many times what the scatter of the
# radius samples around the fit (the mesh's own noise: marching cubes, metaball bumps,
# fused neighbours) would fit by chance is none.
RIPPLE_SIGNAL = 4.0
# The ripple's band, as a share of its angular frequency: its wavelength wanders.
RIPPLE_BAND = (0.6, 1.6)
# Exponents tried by the profile fit.
_EXPONENTS = tuple(np.round(np.arange(0.2, 2.0001, 0.01), 2))


# At most this many trunks are measured, evenly over the icicles (all 933 of a 3 m bunny's
# take 21 GB).
MAX_MEASURED = 200

# Ripple texture (`ripple_texture`): trunks this long and more, radius sampled every
# TEXTURE_STEP in slabs TEXTURE_SLAB thick over TEXTURE_SPAN of the length, compared
# TEXTURE_LAG apart; crests are maxima above CREST_SIGMA standard deviations.
TEXTURE_MIN_LENGTH = 0.10
TEXTURE_STEP = 0.001
TEXTURE_SLAB = 0.0006
TEXTURE_SPAN = (0.2, 0.8)
TEXTURE_LAG = 0.03
CREST_SIGMA = 0.3


@dataclass(frozen=True)
class RippleTexture:
    """How the ripples look along the trunks: medians over trunks of 10 cm and more.

    Attributes
    ----------
    depth_mm : float
        Realised amplitude: sqrt(2) times the standard deviation of the radius, with a
        quadratic trend removed (real: 0.5-1 mm on tap-water icicles).
    correlation_3cm : float
        The detrended radius's autocorrelation 3 cm along, over its variance: near 1 for
        identical stacked rings, low for ripples whose wavelength wanders.
    crest_cv : float
        Crest-to-crest spacing, standard deviation over mean (identical rings: near 0).
    trunks : int
        Trunks measured.
    """

    depth_mm: float
    correlation_3cm: float
    crest_cv: float
    trunks: int

    @classmethod
    def none(cls) -> RippleTexture:
        nan = float("nan")
        return cls(nan, nan, nan, 0)


@dataclass(frozen=True)
class IcicleStats:
    """Plausibility of the icicles, measured on the ice mesh (see `measure_icicles`).

    Per-trunk arrays follow the trunks in branch order, NaN where a trunk is too short to
    measure (fewer than 4 radius samples, under about 7 mm).

    Attributes
    ----------
    tip_radius_mm : float
        Median over trunks of the drop's radius at the tip (real: 2.44 mm); trunks the
        ground cut (`TrajectoryResult.branch_cut`) end in a foot, not a drop, and are left out.
    taper : (i,) float
        Radius at 10 % of the trunk's length below its base over the tip radius (a carrot:
        3 and more; a straw: 1); NaN under `SHAPE_MIN_LENGTH`: at the real growth ratios
        (at most 1/8) a 3 cm icicle's base is under twice its tip, bud rather than carrot.
    growth_ratio : (i,) float
        (base diameter - tip diameter) / length, from the fitted profile taken at the base
        (real icicles: 1/32 to 1/8; length grows 8-32 times faster than width).
    profile_exponent : (i,) float
        n of ``r - tip ~ d^n`` fitted in log-log (real: 3/4; a cone: 1).
    ripple_amplitude_mm : float
        Median over trunks of the amplitude of the radius at the ripple frequency; NaN when
        the icicles have no ripple or it stays under the mesh's own noise.
    ripple_wavelength_cm : float
        Period at the peak of the trunks' radius spectra; NaN with no ripple (as above).
    ripple_texture : RippleTexture
        How natural the ripples are (`ripple_texture`), on trunks of `TEXTURE_MIN_LENGTH`
        and more.
    """

    tip_radius_mm: float
    taper: np.ndarray
    growth_ratio: np.ndarray
    profile_exponent: np.ndarray
    ripple_amplitude_mm: float
    ripple_wavelength_cm: float
    ripple_texture: RippleTexture = field(default_factory=lambda: RippleTexture.none())


def ripple_texture(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult) -> RippleTexture:
    """`RippleTexture` of the trunks of ``traj`` on an ice mesh (``vertices`` (n, 3) in
    meters, ``faces`` (m, 3)).

    The radius around a trunk's axis every `TEXTURE_STEP` is the median distance of the ice
    in a `TEXTURE_SLAB` slab across it: its vertices and where its edges cross the slab's
    mid-plane (`_slab_radius`), over `TEXTURE_SPAN` of its length; a quadratic trend is
    removed.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    trunks = np.flatnonzero((np.asarray(traj.branch_parent) < 0) & (np.diff(off) > 0))
    if len(trunks) == 0 or len(vertices) == 0:
        return RippleTexture.none()
    x_pt, lengths = arc_lengths(traj.points, traj.branch_offsets)
    trunks = trunks[lengths[trunks] >= TEXTURE_MIN_LENGTH]
    if len(trunks) > MAX_MEASURED:
        trunks = trunks[np.linspace(0, len(trunks) - 1, MAX_MEASURED).round().astype(np.int64)]
    if len(trunks) == 0:
        return RippleTexture.none()
    L = lengths[trunks]
    lo, hi = TEXTURE_SPAN
    n = ((hi - lo) * L / TEXTURE_STEP).astype(np.int64) + 1
    owner = np.repeat(np.arange(len(trunks)), n)
    k = ragged_arange(n)
    x = (lo * L)[owner] + k * TEXTURE_STEP
    axis, tangent = points_along(traj, x_pt, lengths, trunks[owner], x)
    r = _slab_radius(axis, tangent, vertices, point_index(vertices), faces, owner, x, TEXTURE_STEP, TEXTURE_SLAB,
                     0.002)
    return _texture([r[owner == j] for j in range(len(trunks))])


def _texture(profiles: list[np.ndarray]) -> RippleTexture:
    """`RippleTexture` of trunks' radius profiles (meters), each sampled every
    `TEXTURE_STEP` over `TEXTURE_SPAN` of its trunk's length."""
    lag = int(round(TEXTURE_LAG / TEXTURE_STEP))
    depth, corr, cv = [], [], []
    for rj in profiles:
        if len(rj) < 3:
            continue
        u = np.linspace(-1.0, 1.0, len(rj))
        rest = rj - np.polyval(np.polyfit(u, rj, 2), u)
        sigma = float(rest.std())
        if not sigma > 0:
            continue
        depth.append(math.sqrt(2.0) * sigma)
        if len(rest) > lag + 10:
            corr.append(float(np.mean(rest[:-lag] * rest[lag:]) / sigma**2))
        inner = rest[1:-1]
        crest = np.flatnonzero((inner > rest[:-2]) & (inner >= rest[2:]) & (inner > CREST_SIGMA * sigma)) + 1
        if len(crest) >= 3:
            gaps = np.diff(crest).astype(np.float64)
            cv.append(float(gaps.std() / gaps.mean()))
    med = lambda v, scale=1.0: float(np.median(v) * scale) if v else float("nan")  # noqa: E731
    return RippleTexture(med(depth, 1000.0), med(corr), med(cv), len(depth))


def measure_icicles(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult,
                    surface: SurfaceParams, sample_step: float = 0.001) -> IcicleStats:
    """Physical plausibility of the icicles, measured on the ice mesh.

    The radius of a trunk at arc length x is the median distance from its axis of the ice in
    a `TEXTURE_SLAB` slab across it (its vertices and where its edges cross the slab's
    mid-plane, `_slab_radius`), sampled every ``sample_step`` from ``TAPER_AT`` of its
    length to ``FIT_END``. The ripple texture reads the same samples over `TEXTURE_SPAN`
    of the trunks of `TEXTURE_MIN_LENGTH` and more (one pass over the mesh, not two).

    Parameters
    ----------
    vertices : (n, 3) float
        In meters.
    faces : (m, 3) int
    traj : TrajectoryResult
    surface : SurfaceParams
        The resolved ``surface`` group (tip radius, ripple amplitude, impurity, frequency).
    sample_step : float
        Spacing of the radius samples along each trunk, in meters.

    Returns
    -------
    IcicleStats
    """
    nan = float("nan")
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    trunks = np.flatnonzero(np.asarray(traj.branch_parent) < 0)
    trunks = trunks[np.diff(off)[trunks] > 0]
    if len(trunks) > MAX_MEASURED:  # evenly over the icicles: the figures are medians
        trunks = trunks[np.linspace(0, len(trunks) - 1, MAX_MEASURED).round().astype(np.int64)]
    empty = np.full(len(trunks), np.nan)
    if len(trunks) == 0 or len(faces) == 0:
        return IcicleStats(nan, empty, empty.copy(), empty.copy(), nan, nan)
    x_pt, lengths = arc_lengths(traj.points, traj.branch_offsets)
    pts = np.asarray(traj.points, dtype=np.float64)
    index = point_index(vertices)

    tips = pts[off[trunks + 1] - 1]
    direction = tips - pts[np.maximum(off[trunks + 1] - 2, off[trunks])]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-300)
    tip_d = _tip_radius(tips, direction, vertices, index)
    cut = traj.cut[trunks]
    grown_all = grown_lengths(lengths[trunks], cut)
    tip_d[cut > 0] = np.nan  # its end stands on the ground: a column's foot, not a drop
    tip_mm = float(np.nanmedian(tip_d) * 1000) if np.isfinite(tip_d).any() else nan

    # Radius samples along every trunk, all queried at once.
    L = lengths[trunks]
    span = (1 - TAPER_AT - (1 - FIT_END)) * L
    n = np.maximum((span / sample_step).astype(np.int64), 0) + 1
    ok = n >= 4
    n = np.where(ok, n, 0)
    owner = np.repeat(np.arange(len(trunks)), n)
    k = ragged_arange(n)
    x = (TAPER_AT * L)[owner] + k * sample_step
    axis, tangent = points_along(traj, x_pt, lengths, trunks[owner], x)
    r = _slab_radius(axis, tangent, vertices, index, faces, owner, x, sample_step, TEXTURE_SLAB,
                     2 * surface.ripple_amplitude * surface.impurity)

    tip = surface.tip_radius
    amplitude = surface.ripple_amplitude * surface.impurity
    fs = surface.ripple_frequency
    taper, growth, exponent = empty.copy(), empty.copy(), empty.copy()
    amplitudes, spectra, textured = [], [], []
    lo, hi = TEXTURE_SPAN
    for j in np.flatnonzero(ok):
        sel = owner == j
        xj, rj = x[sel], r[sel]
        if L[j] >= TEXTURE_MIN_LENGTH:
            textured.append(rj[(xj >= lo * L[j]) & (xj <= hi * L[j])])
        if L[j] >= SHAPE_MIN_LENGTH:
            taper[j] = rj[0] / tip
        grown = grown_all[j]  # the profile of a cut icicle runs on below the ground
        d = grown - xj
        # Clear of the base ice too, which swells the first centimetres below the drip point.
        fit = (d >= FIT_START * grown) & (d <= FIT_END * grown) & (xj >= 0.5 * surface.base_extent)
        if fit.sum() >= 4:
            n_j, k_j = _power_fit(d[fit], rj[fit] - tip)
            exponent[j] = n_j
            growth[j] = 2 * k_j * grown ** n_j / grown
        if len(xj) >= 8:
            u = (xj - xj.mean()) / max(np.ptp(xj), 1e-300)
            trend = np.polyval(np.polyfit(u, rj, 3), u)
            residual = rj - trend
            spectra.append(residual * np.hanning(len(rj)))
            if amplitude > 0 and fs > 0 and np.ptp(xj) * fs >= 4 * math.pi:  # two ripples or more
                amplitudes.append(_band_amplitude(residual, sample_step, fs))
    ripple_mm = wavelength = nan
    if amplitudes:
        amp, noise = np.median(np.array(amplitudes), axis=0)
        if amp > RIPPLE_SIGNAL * noise:
            ripple_mm = float(amp * 1000)
            wavelength = _dominant_period(spectra, sample_step) * 100
    texture = (_texture(textured) if sample_step == TEXTURE_STEP
               else ripple_texture(vertices, faces, traj))
    return IcicleStats(tip_mm, taper, growth, exponent, ripple_mm, wavelength, texture)


def _band_amplitude(residual: np.ndarray, step: float, fs: float) -> tuple[float, float]:
    """``(amplitude, noise)`` (meters) of the ripple in a radius profile sampled every
    ``step``: the sine amplitude of the power within `RIPPLE_BAND` of ``fs`` (a ripple
    whose wavelength wanders stays in it), and what the profile's power density beyond
    that band (the mesh's own noise) would put in it, as an amplitude."""
    n = len(residual)
    power = np.abs(np.fft.rfft(residual)) ** 2 * (2.0 / n**2)  # each bin's share of the variance
    omega = 2 * np.pi * np.fft.rfftfreq(n, step)
    lo, hi = RIPPLE_BAND
    band = (omega >= lo * fs) & (omega <= hi * fs)
    beyond = omega > 1.5 * hi * fs
    amp = math.sqrt(2.0 * power[band].sum())
    noise_density = float(power[beyond].mean()) if beyond.any() else 0.0
    noise = math.sqrt(2.0 * noise_density * max(band.sum(), 1))
    return amp, noise


def _slab_radius(axis, tangent, vertices, index, faces, trunk, x, step, thickness, slack):
    """Radius of the ice around each axis point (k, 3): the median distance from the axis of
    the ice in a slab ``thickness`` thick across it, within ``slack`` (and a margin) of the
    nearest vertex's distance (``index``: `icefarm.spatial.point_index` of ``vertices``);
    the nearest vertex's distance where the slab is empty.

    The ice in a slab is its vertices and the points where the mesh's edges (``faces``
    (m, 3)) cross the point's plane across the axis (`_crossings`; each axis point's trunk
    ``trunk`` (k,) and arc length ``x`` (k,), its trunk's points ``step`` apart and in
    order). Vertices alone leave a slab thinner than the mesh's vertex spacing empty every
    other step, and the nearest vertex, which under-reads, would stand in: on the eaves (2 mm
    voxel) the radius sampled every 1 mm in 0.6 mm slabs alternates by about 0.5 mm, half
    the crest spacings read 2 mm, and the ripple's band drowns in that noise.

    Each vertex belongs to the slab of its nearest axis point, as it does to the planes it
    crosses: one nearest-point query for the mesh, not a ball query per slab (see
    `measure_icicles`).
    """
    if len(axis) == 0:
        return np.zeros(0)
    near = nearest(index, axis)[0]
    reach = near + slack + thickness
    bound = float(reach.max())
    box = within_box(vertices, axis.min(axis=0) - bound, axis.max(axis=0) + bound)
    candidates = np.flatnonzero(box)
    dist, k = nearest(point_index(axis), vertices[candidates], bound)
    found = (k >= 0) & (dist <= reach[np.maximum(k, 0)])
    vert, k = candidates[found], k[found]
    rel = vertices[vert] - axis[k]
    along = np.einsum("ij,ij->i", rel, tangent[k])
    radial = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - along**2, 0.0))
    slab = np.abs(along) <= 0.5 * thickness
    c_owner, c_radial = _crossings(vert, k, along, radial, len(vertices), faces, trunk, x, step)
    keep = c_radial <= reach[c_owner]
    owner = np.concatenate([k[slab], c_owner[keep]])
    radial = np.concatenate([radial[slab], c_radial[keep]])
    # The median of each sample's slab: sort by (sample, radius), take the middle entries.
    # One key, the sample plus the radius scaled under 1: half lexsort's time (the bench's
    # 3 M entries), the same order but for radii within 1e-12 of the largest of each other.
    order = np.argsort(owner + radial / (2.0 * max(float(radial.max(initial=0.0)), 1e-300)))
    owner, radial = owner[order], radial[order]
    n = np.bincount(owner, minlength=len(axis))
    start = np.cumsum(n) - n
    out = near.copy()
    has = n > 0
    lo = start[has] + (n[has] - 1) // 2
    hi = start[has] + n[has] // 2
    out[has] = 0.5 * (radial[lo] + radial[hi])
    return out


def _crossings(vert, sample, along, radial, n_vertices, faces, trunk, x, step):
    """``(sample, radius)`` of each point where a mesh edge crosses the plane across the
    axis at an axis sample: the sample's index, and the point's distance from the axis.

    ``vert`` (v,) are the vertices near the axis, ``sample`` (v,) the nearest axis sample of
    each, ``along`` (v,) its offset along that sample's tangent and ``radial`` (v,) its
    distance from the axis; ``n_vertices`` the mesh's. Each such vertex lies on its sample's
    trunk (``trunk`` (k,)) at arc length ``x`` (k,) plus its offset; an edge whose two ends
    lie on one trunk crosses the planes of that trunk's samples (``step`` apart, in order)
    between their arc lengths, at the radius interpolated between them. One pass over the
    edges, not one per plane: on the table (lookdev), `measure_icicles` runs 2.5 to 3 times
    faster this way than with the edges at each plane searched for the crossing.
    """
    return edge_crossings(np.ascontiguousarray(faces, dtype=np.int64),
                          _on_trunks(vert, sample, along, radial, n_vertices, trunk, x), _trunk_starts(trunk),
                          (np.asarray(x, dtype=np.float64), float(step)))


def _on_trunks(vert, sample, along, radial, n_vertices, trunk, x):
    """Per mesh vertex (``n_vertices``): its arc length along its trunk, its distance from
    the axis (NaN both) and its trunk (-1) where it is not one of the ``vert`` near an axis
    (arguments as `_crossings`)."""
    s = np.full(n_vertices, np.nan)
    r = np.full(n_vertices, np.nan)
    t = np.full(n_vertices, -1, dtype=np.int64)
    s[vert] = x[sample] + along
    r[vert] = radial
    t[vert] = trunk[sample]
    return s, r, t


def _trunk_starts(trunk):
    """Per trunk, its first axis sample and how many it has (``trunk`` (k,), sorted)."""
    first = np.searchsorted(trunk, np.arange(int(trunk.max()) + 1))
    return first, np.bincount(trunk, minlength=len(first))


def _power_fit(d: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """``(n, k)`` of ``y = k d^n`` by least squares in y over a grid of n.

    Fitting in y, not in log y, keeps the samples near the tip (where y is small and the
    mesh's noise is a large share of it) from pulling n.
    """
    n = np.asarray(_EXPONENTS)[:, None]
    basis = d[None, :] ** n
    k = (basis @ y) / np.maximum((basis * basis).sum(axis=1), 1e-300)
    best = int(np.argmin(((y[None, :] - k[:, None] * basis) ** 2).sum(axis=1)))
    return float(_EXPONENTS[best]), float(k[best])


def _tip_radius(points, directions, vertices, index):
    """Per tip point (p, 3) with its unit growth direction: the median distance to the mesh
    vertices (which lie on the iso-surface) ahead of the tip and within 1.5 times the
    nearest one (``index``: `icefarm.spatial.point_index` of ``vertices``), i.e. the radius
    of the drop that closes the icicle."""
    d_near, _ = nearest(index, points)
    out = np.full(len(points), np.nan)
    ball = 1.5 * d_near
    # a tree of the vertices around the tips only
    d_tip, _ = nearest(point_index(points), vertices, float(ball.max(initial=0.0)))
    near = np.flatnonzero(np.isfinite(d_tip))
    for i, idx in enumerate(cKDTree(vertices[near]).query_ball_point(points, ball)):
        rel = vertices[near[np.asarray(idx, dtype=np.int64)]] - points[i]
        ahead = rel @ directions[i] >= 0
        if ahead.any():
            out[i] = np.median(np.linalg.norm(rel[ahead], axis=1))
    return out


def _dominant_period(profiles, step):
    """Period (m) at the peak of the summed, per-profile normalised power spectra of
    ``profiles`` (list of 1-D arrays sampled every ``step`` meters), past the lowest bins."""
    size = 1 << int(math.ceil(math.log2(4 * max(len(p) for p in profiles))))
    freq = np.fft.rfftfreq(size, step)
    power = np.zeros(len(freq))
    for p in profiles:
        spec = np.abs(np.fft.rfft(p, size)) ** 2
        if spec.sum() > 0:
            power += spec / spec.sum()
    # Periods longer than half the longest profile are trend, not ripple.
    longest = max(len(p) for p in profiles) * step
    power[freq < 2.0 / longest] = 0.0
    if not power.any():
        return float("nan")
    return float(1.0 / freq[np.argmax(power)])
