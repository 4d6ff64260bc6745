"""The tree branch with side twigs: tapered tubes swept along Bezier curves and fused by a
boolean union.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..geometry import unit
from ._common import DEFAULT_DETAIL, grid_faces, rest_on_ground


def branch(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A bent, tapered tree branch with three side twigs, one closed manifold.

    The main branch runs about 1.1 along +x, rising then drooping, its radius tapering
    from 0.045 (flat cut end at x = 0) to 0.012 (rounded tip); three twigs (radius 0.6 of
    the branch where they leave it, tapering to 0.005, rounded tips) leave it at 30, 55
    and 78 % of its length. Tubes are swept along Bezier curves and fused by a boolean
    union (manifold3d); the branch and twig tubes get ``2 detail`` and ``1.5 detail``
    sides.
    """
    sides = max(8, 2 * detail)
    t = np.linspace(0.0, 1.0, max(8, 6 * detail) + 1)
    main = bezier_curve([[0.0, 0.30, 0.0], [0.40, 0.44, 0.04], [0.75, 0.40, 0.16],
                         [1.10, 0.28, 0.14]], t)
    main_radius = 0.045 - 0.033 * t ** 0.8
    tubes = [tube(main, main_radius, sides)]
    twig_t = np.linspace(0.0, 1.0, max(4, 2 * detail) + 1)
    for at, bend, tip in _TWIGS:
        k = np.searchsorted(t, at)
        start = main[k]
        path = bezier_curve([start, start + np.asarray(bend), start + np.asarray(tip)], twig_t)
        radius = 0.6 * main_radius[k] * (1 - twig_t) + 0.005 * twig_t
        tubes.append(tube(path, radius, max(6, round(1.5 * detail))))
    mesh = trimesh.boolean.union(tubes, engine="manifold")
    return rest_on_ground(mesh)


# (where along the branch, second control point, end point; both relative to the start)
_TWIGS = (
    (0.30, (0.10, 0.16, -0.04), (0.22, 0.30, -0.14)),
    (0.55, (0.12, 0.06, 0.12), (0.30, 0.16, 0.26)),
    (0.78, (0.08, 0.10, -0.10), (0.20, 0.12, -0.24)),
)


def bezier_curve(control, t: np.ndarray) -> np.ndarray:
    """Points of a Bezier curve of any degree.

    Parameters
    ----------
    control : (m, d) float
        m >= 2 control points.
    t : (k,) float
        Parameters in [0, 1].

    Returns
    -------
    (k, d) float
    """
    control = np.asarray(control, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[:, None]
    degree = len(control) - 1
    if control.ndim != 2 or degree < 1:
        raise ValueError(f"control must have shape (m >= 2, d), got {control.shape}")
    i = np.arange(degree + 1)
    binom = np.array([math.comb(degree, k) for k in i], dtype=np.float64)
    basis = binom * t ** i * (1 - t) ** (degree - i)
    return basis @ control


def tube(centerline: np.ndarray, radii: np.ndarray, sides: int, tip_rings: int = 3) -> trimesh.Trimesh:
    """Sweep a circle along a polyline into a closed tube: flat start, rounded end.

    Parameters
    ----------
    centerline : (k, 3) float
        k >= 2 points; the curve must bend gently (it may not run along the axis least
        aligned with its chord).
    radii : (k,) float
        Positive radius at each point.
    sides : int
        Vertices around each ring (>= 3).
    tip_rings : int
        Rings of the hemispherical cap at the end, before its apex.

    Returns
    -------
    trimesh.Trimesh
        Closed, outward-facing.
    """
    centerline = np.asarray(centerline, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    if centerline.ndim != 2 or centerline.shape[1] != 3 or len(centerline) < 2:
        raise ValueError(f"centerline must have shape (k >= 2, 3), got {centerline.shape}")
    if radii.shape != (len(centerline),) or (radii <= 0).any():
        raise ValueError("radii must be positive, one per centerline point")
    if sides < 3:
        raise ValueError(f"sides must be >= 3, got {sides}")
    tangent = unit(np.gradient(centerline, axis=0))
    # Round the end: extra rings on a quarter circle, the last one collapsing to the apex.
    angle = np.arange(1, tip_rings + 2) * (0.5 * np.pi / (tip_rings + 1))
    end = centerline[-1] + np.outer(np.sin(angle), tangent[-1]) * radii[-1]
    centerline = np.concatenate([centerline, end])
    radii = np.concatenate([radii, radii[-1] * np.cos(angle[:-1])])
    tangent = np.concatenate([tangent, np.repeat(tangent[-1:], len(angle), axis=0)])
    # Frames from one fixed reference: no twist, fine for curves that bend gently.
    chord = centerline[-1] - centerline[0]
    reference = np.eye(3)[np.argmin(np.abs(chord))]
    if (np.abs(tangent @ reference) > 0.99).any():
        raise ValueError("centerline turns too far from its chord for a twist-free frame")
    normal = unit(reference - (tangent @ reference)[:, None] * tangent)
    binormal = np.cross(tangent, normal)
    phi = np.arange(sides) * (2 * np.pi / sides)
    rings = centerline[:-1, None] + radii[:, None, None] * (
        np.cos(phi)[None, :, None] * normal[:-1, None] + np.sin(phi)[None, :, None] * binormal[:-1, None])
    count = len(rings)
    vertices = np.concatenate([rings.reshape(-1, 3), centerline[:1], centerline[-1:]])
    start, apex = count * sides, count * sides + 1
    j = np.arange(sides)
    nxt = (j + 1) % sides
    last = (count - 1) * sides
    faces = np.concatenate([
        np.stack([np.full_like(j, start), nxt, j], axis=1),
        grid_faces(count, sides, wrap=True)[:, ::-1],
        np.stack([last + j, last + nxt, np.full_like(j, apex)], axis=1),
    ])
    return trimesh.Trimesh(vertices, faces, process=False)
