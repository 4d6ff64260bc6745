"""Each branch swept as a closed tube (``surface.mode: tubes``, the paper's future work 6.1)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...geometry import arc_lengths, ragged_arange
from ...params import SurfaceParams
from ..trajectories import TrajectoryResult
from .icicles import perpendicular_frame
from .profile import grown_lengths, points_along, profile_args, profile_radius


def tube_mesh(traj: TrajectoryResult, surface: SurfaceParams, gravity=(0.0, -1.0, 0.0), ring: int = 12,
              cap_rings: int = 4):
    """Each branch as a closed tube: Equation 1's profile swept along the branch with
    rotation-minimising frames, a hemisphere of the tip radius at the tip and one of the
    base radius at the base (paper 6.1: the icicles' mesh directly, no metaballs).

    Parameters
    ----------
    traj : TrajectoryResult
    surface : SurfaceParams
        The resolved ``surface`` group.
    gravity : (3,) float
        Each tube's first frame starts from gravity (seams line up from run to run).
    ring : int
        Vertices per ring.
    cap_rings : int
        Rings in each hemisphere, besides its pole.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound; each branch's tube is closed (watertight) on its own.
    """
    prof = profile_args(surface)
    tip = prof.tip
    x_pt, lengths = arc_lengths(traj.points, traj.branch_offsets)
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if len(branches) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    step = tip
    if prof.amplitude > 0 and prof.frequency > 0:
        step = min(step, 2 * math.pi / prof.frequency / 6)
    L = lengths[branches]
    n = np.maximum(np.ceil(L / step).astype(np.int64), 1) + 1  # body rings per tube
    rb = np.repeat(np.arange(len(branches)), n)
    first = np.cumsum(n) - n
    rk = ragged_arange(n)
    xr = rk * (L / (n - 1))[rb]
    centre, _ = points_along(traj, x_pt, lengths, branches[rb], xr)
    growth = traj.growth(prof.growth)[branches]
    radius = profile_radius(xr, grown_lengths(L, traj.cut[branches])[rb], dataclasses.replace(prof, growth=growth[rb]))
    # Tangents by central differences within each tube (one-sided at its ends).
    last = first + n - 1
    ahead = centre[np.minimum(np.arange(len(rb)) + 1, last[rb])]
    behind = centre[np.maximum(np.arange(len(rb)) - 1, first[rb])]
    tangent = ahead - behind
    norm = np.linalg.norm(tangent, axis=1, keepdims=True)
    down = np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity)
    tangent = np.where(norm > 0, tangent / np.maximum(norm, 1e-300), down)
    normal = _transport_frames(centre, tangent, first, n, gravity)
    binormal = np.cross(tangent, normal)

    # Rings in order along each tube: base hemisphere, body, tip hemisphere.
    dphi = 0.5 * math.pi / (cap_rings + 1)
    k = len(branches)
    per = n + 2 * cap_rings
    start = np.cumsum(per) - per
    total = int(per.sum())
    rc, rr = np.empty((total, 3)), np.empty(total)
    rn, rbn = np.empty((total, 3)), np.empty((total, 3))
    body = start[rb] + cap_rings + rk
    rc[body], rr[body], rn[body], rbn[body] = centre, radius, normal, binormal
    for i in range(cap_rings):
        for end, sign, at in ((first, -1.0, start + i), (last, 1.0, start + cap_rings + n + i)):
            phi = (cap_rings - i) * dphi if sign < 0 else (i + 1) * dphi
            rc[at] = centre[end] + sign * math.sin(phi) * radius[end, None] * tangent[end]
            rr[at] = math.cos(phi) * radius[end]
            rn[at], rbn[at] = normal[end], binormal[end]
    theta = np.arange(ring) * (2 * math.pi / ring)
    verts = rc[:, None, :] + rr[:, None, None] * (np.cos(theta)[None, :, None] * rn[:, None, :]
                                                  + np.sin(theta)[None, :, None] * rbn[:, None, :])
    poles = np.concatenate([centre[first] - radius[first, None] * tangent[first],
                            centre[last] + radius[last, None] * tangent[last]])
    vertices = np.concatenate([verts.reshape(-1, 3), poles])

    # Quads between consecutive rings of a tube, fans to the poles.
    has_next = np.ones(total, dtype=bool)
    has_next[start + per - 1] = False
    lower = np.flatnonzero(has_next)
    j = np.arange(ring)
    a = lower[:, None] * ring + j
    b = lower[:, None] * ring + (j + 1) % ring
    quads = np.concatenate([np.stack([a, b, b + ring], -1).reshape(-1, 3),
                            np.stack([a, b + ring, a + ring], -1).reshape(-1, 3)])
    pole_base = total * ring + np.arange(k)
    pole_tip = total * ring + k + np.arange(k)
    ring0 = start[:, None] * ring
    ring1 = (start + per - 1)[:, None] * ring
    fan_b = np.stack([np.repeat(pole_base[:, None], ring, 1), ring0 + (j + 1) % ring, ring0 + j], -1)
    fan_t = np.stack([np.repeat(pole_tip[:, None], ring, 1), ring1 + j, ring1 + (j + 1) % ring], -1)
    faces = np.concatenate([quads, fan_b.reshape(-1, 3), fan_t.reshape(-1, 3)]).astype(np.int64)
    return vertices, faces


def _transport_frames(centre, tangent, first, n, gravity) -> np.ndarray:
    """Rotation-minimising normals along many polylines at once (double reflection, Wang et
    al. 2008); polyline ``i`` is ``centre[first[i]:first[i] + n[i]]``. Each starts from
    gravity made perpendicular to its first tangent."""
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    t0 = tangent[first]
    n0 = g - (t0 @ g)[:, None] * t0
    bad = np.linalg.norm(n0, axis=1) < 1e-6
    if bad.any():
        n0[bad] = perpendicular_frame(t0[bad])[0]
    normal = np.empty_like(centre)
    normal[first] = n0 / np.linalg.norm(n0, axis=1, keepdims=True)
    for step in range(int(n.max()) - 1):
        live = first[n > step + 1] + step
        nxt = live + 1
        v1 = centre[nxt] - centre[live]
        c1 = np.maximum(np.einsum("ij,ij->i", v1, v1), 1e-300)[:, None]
        r_l = normal[live] - (2 / c1) * np.einsum("ij,ij->i", v1, normal[live])[:, None] * v1
        t_l = tangent[live] - (2 / c1) * np.einsum("ij,ij->i", v1, tangent[live])[:, None] * v1
        v2 = tangent[nxt] - t_l
        c2 = np.einsum("ij,ij->i", v2, v2)[:, None]
        r = r_l - (2 / np.maximum(c2, 1e-300)) * np.einsum("ij,ij->i", v2, r_l)[:, None] * v2
        r = np.where(c2 > 1e-30, r, r_l)
        r -= np.einsum("ij,ij->i", r, tangent[nxt])[:, None] * tangent[nxt]
        normal[nxt] = r / np.linalg.norm(r, axis=1, keepdims=True)
    return normal
