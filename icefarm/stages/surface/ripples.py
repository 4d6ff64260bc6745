"""Ripples carved into the icicles of the ice mesh (paper 4.4.1, Equation 1's ``as sin(x fs)``).

A chain of Gaussian balls of width s keeps ``exp(-(fs s / 2)^2)`` of a ripple along it: at
1 cm ripples, 3 % on a 1 cm thick base, 70 % at the tip (measured: 0.07 mm realised of
0.6 mm asked on a 12 cm icicle). So the chains carry the smooth profile and the ripple is a
displacement of the mesh's vertices around each branch, which keeps the mesh watertight
and the ripple exactly as deep as asked, at any frequency the voxel resolves.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..trajectories import TrajectoryResult
from .profile import _branch_lengths, _points_along, grown_lengths, ripple, smooth_radius

# Vertices farther from a branch's axis than this times its radius there (plus the ripple)
# belong to something else: a neighbour, the base ice, the glaze.
REACH = 1.3
# Ripples come in as the icicle widens: full once its radius exceeds the tip's by this
# many tip radii. A thin young icicle is smooth; a 0.7 mm ripple on a 3 mm straw reads as a
# string of beads (seen at lookdev), while on real icicles ripples run on the wide part.
RIPPLE_WIDENING = 1.0
GOLDEN_ANGLE = np.pi * (3 - np.sqrt(5))
# Axis samples per ripple wavelength (and at least one per tip radius).
SAMPLES_PER_WAVE = 16


def carve_ripples(vertices: np.ndarray, traj: TrajectoryResult, prof: dict,
                  max_radius: float | None = None) -> np.ndarray:
    """Move the ice mesh's vertices around each branch radially by the profile's ripple.

    Each vertex follows the nearest sample of the branch axes: at arc length x of a branch,
    it moves by ``as sin(x fs)`` (faded at the tip as in `profile_radius`, in over the
    first base radius of the branch, where it meets the object, and in as the radius widens
    past the tip's, `RIPPLE_WIDENING`) away from the axis.

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices, in meters.
    traj : TrajectoryResult
    prof : dict
        `profile_args` of the surface group (``amplitude`` is ``as * impurity``).
    max_radius : float, optional
        Ripples fade out from 0.8 of this radius to it (meters): where the icicles are
        thicker, their mesh is too coarse to carry them (`icefarm.stages.surface.detail`)
        and the error budget is coarser than they are deep.

    Returns
    -------
    (n, 3) float
        The moved vertices (a copy); the same array when there is no ripple.
    """
    amplitude, frequency, tip = prof["amplitude"], prof["frequency"], prof["tip"]
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if amplitude <= 0 or frequency <= 0 or len(branches) == 0 or len(vertices) == 0:
        return vertices
    x_pt, lengths = _branch_lengths(traj)
    L = lengths[branches]
    grown = grown_lengths(L, traj.cut[branches])
    prof = dict(prof)
    growth = traj.growth(prof.pop("growth"))[branches]
    step = min(2 * np.pi / frequency / SAMPLES_PER_WAVE, tip)
    n = np.ceil(L / step).astype(np.int64) + 1
    owner = np.repeat(np.arange(len(branches)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    x = k * (L / np.maximum(n - 1, 1))[owner]
    axis, tangent = _points_along(traj, x_pt, lengths, branches[owner], x)
    radius = smooth_radius(x, grown[owner], growth=growth[owner], **prof)
    # Each branch's rings start at their own phase (the golden angle apart: no draw from the
    # stage's stream): neighbours in phase stacked into a column of glass plates at lookdev.
    phase = (branches * GOLDEN_ANGLE) % (2 * np.pi)
    wave = ripple(x, grown[owner], tip, amplitude, frequency, phase[owner]) \
        * np.clip(x / smooth_radius(0.0, grown[owner], growth=growth[owner], **prof), 0, 1)
    wave *= np.clip((radius - tip) / (RIPPLE_WIDENING * tip), 0, 1)
    if max_radius is not None:
        wave *= np.clip((max_radius - radius) / (0.2 * max_radius), 0, 1)

    reach = REACH * radius.max() + amplitude
    d, i = cKDTree(axis).query(vertices, distance_upper_bound=reach)
    near = np.flatnonzero(np.isfinite(d))
    i = i[near]
    rel = vertices[near] - axis[i]
    radial = rel - np.einsum("ij,ij->i", rel, tangent[i])[:, None] * tangent[i]
    dist = np.linalg.norm(radial, axis=1)
    own = (dist <= REACH * radius[i] + amplitude) & (dist > 1e-9)
    out = np.array(vertices, dtype=np.float64, copy=True)
    sel = near[own]
    out[sel] += (wave[i[own]] / dist[own])[:, None] * radial[own]
    return out
