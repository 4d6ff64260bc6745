"""Physical plausibility of the icicles, measured on the ice mesh."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..trajectories import TrajectoryResult
from .profile import _branch_lengths, _points_along

def measure_icicles(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult,
                    surface: dict, sample_step: float = 0.001):
    """Physical plausibility of the icicles, measured on the ice mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        In meters.
    faces : (m, 3) int
    traj : TrajectoryResult
    surface : dict
        The resolved ``surface`` group (only ``ripple_amplitude`` is read: 0 means no ripple).
    sample_step : float
        Spacing of the radius samples along each trunk, in meters.

    Returns
    -------
    tip_radius_mm : float
        Median over trunks of the distance from the tip point to the ice ahead of it (median
        over the drop's mesh vertices, which lie on the iso-surface).
    length_to_diameter : (i,) float
        Per trunk, its length over twice the base radius of a line fitted to its radius
        (distance from the axis to the nearest vertex) between 30 % and 90 % of its length,
        taken at x = 0; nan for a trunk with fewer than 4 samples there (shorter than
        ``4 sample_step / 0.6``) or whose fitted base radius is not positive.
    ripple_wavelength_cm : float
        Peak of the trunks' radius spectra (quadratic trend removed, Hann window, each trunk
        normalised), in centimeters; nan when the ripple amplitude is 0 or no trunk spans
        eight samples.
    """
    nan = float("nan")
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    trunks = np.flatnonzero(np.asarray(traj.branch_parent) < 0)
    trunks = trunks[np.diff(off)[trunks] > 0]
    if len(trunks) == 0 or len(faces) == 0:
        return nan, np.full(len(trunks), np.nan), nan
    x_pt, lengths = _branch_lengths(traj)
    pts = np.asarray(traj.points, dtype=np.float64)
    tree = cKDTree(vertices, balanced_tree=False, compact_nodes=False)

    tips = pts[off[trunks + 1] - 1]
    direction = tips - pts[np.maximum(off[trunks + 1] - 2, off[trunks])]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-300)
    tip_d = _tip_radius(tips, direction, vertices, tree)
    tip_mm = float(np.nanmedian(tip_d) * 1000) if np.isfinite(tip_d).any() else nan

    # Radius samples along the free part of every trunk, all queried at once.
    L = lengths[trunks]
    n = np.maximum((0.6 * L / sample_step).astype(np.int64), 0) + 1
    ok = n >= 4
    n = np.where(ok, n, 0)
    owner = np.repeat(np.arange(len(trunks)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    x = (0.3 * L)[owner] + k * sample_step
    axis, _ = _points_along(traj, x_pt, lengths, trunks[owner], x)
    r = tree.query(axis)[0] if len(axis) else np.zeros(0)

    ratios = np.full(len(trunks), np.nan)
    spectra = []
    for j in np.flatnonzero(ok):
        sel = owner == j
        xj, rj = x[sel], r[sel]
        A = np.stack([np.ones_like(xj), L[j] - xj], axis=1)
        (a0, slope), *_ = np.linalg.lstsq(A, rj, rcond=None)
        base = a0 + max(slope, 0.0) * L[j]
        if base > 0:
            ratios[j] = L[j] / (2 * base)
        if len(xj) >= 8:
            u = (xj - xj.mean()) / max(np.ptp(xj), 1e-300)
            trend = np.polyval(np.polyfit(u, rj, 2), u)
            spectra.append((rj - trend) * np.hanning(len(rj)))
    wavelength = nan
    if surface["ripple_amplitude"] > 0 and spectra:
        wavelength = _dominant_period(spectra, sample_step) * 100
    return tip_mm, ratios, wavelength


def _tip_radius(points, directions, vertices, tree):
    """Per tip point (p, 3) with its unit growth direction: the median distance to the mesh
    vertices (which lie on the iso-surface) ahead of the tip and within 1.5 times the
    nearest one, i.e. the radius of the drop that closes the icicle."""
    d_near, _ = tree.query(points)
    out = np.full(len(points), np.nan)
    for i, idx in enumerate(tree.query_ball_point(points, 1.5 * d_near)):
        rel = vertices[np.asarray(idx, dtype=np.int64)] - points[i]
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
