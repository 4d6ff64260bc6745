"""The two-basin garden fountain: a profile, resampled and revolved into a closed surface
(after Kim et al.'s fountain, the paper's Fig. 16 b).
"""

from __future__ import annotations

import numpy as np
import trimesh

from ..geometry import ragged_arange
from ._common import DEFAULT_DETAIL, grid_faces, rest_on_ground


def fountain(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A two-basin garden fountain, one closed manifold: a surface of revolution about +y.

    A wide lower basin (radius 1, wall top at y = 0.3, a bead overhanging its outer wall),
    a column, an upper bowl (radius 0.58) whose rim carries an outward drip lip, so water
    on it leaves from overhanging edges above the lower basin, and a small finial at
    y = 1.17. Its outline is `_FOUNTAIN_PROFILE`, evenly subdivided. At the default
    detail the profile has 41 pieces and the lathe 28 sectors, giving 2,240 faces, the
    polygon count of the paper's Figure 16 b input.
    """
    around = max(8, round(3.5 * detail))
    pieces = max(len(_FOUNTAIN_PROFILE) - 1, round(41 * detail / 8))
    profile = resample_polyline(_FOUNTAIN_PROFILE, pieces, weights=_FOUNTAIN_WEIGHTS)
    vertices, faces = lathe(profile, around)
    return rest_on_ground(trimesh.Trimesh(vertices, faces, process=False))


def lathe(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Revolve a profile about the y axis into a closed surface.

    Parameters
    ----------
    profile : (k, 2) float
        ``(radius, y)`` points, k >= 3. The first and last lie on the axis (radius 0),
        the others off it; together with the axis they bound a simple polygon that runs
        counter-clockwise (outwards along the bottom first), so normals face outwards.
    segments : int
        Divisions around the axis (>= 3).

    Returns
    -------
    vertices : ((k - 2) * segments + 2, 3) float
    faces : (segments * (2 * k - 4), 3) int
        A closed 2-manifold when the profile polygon is simple.
    """
    profile = np.asarray(profile, dtype=np.float64)
    if profile.ndim != 2 or profile.shape[1] != 2 or len(profile) < 3:
        raise ValueError(f"profile must have shape (k >= 3, 2), got {profile.shape}")
    if profile[0, 0] != 0 or profile[-1, 0] != 0 or (profile[1:-1, 0] <= 0).any():
        raise ValueError("profile must start and end on the axis (radius 0) and stay off it between")
    if segments < 3:
        raise ValueError(f"segments must be >= 3, got {segments}")
    inner = profile[1:-1]
    theta = np.arange(segments) * (2 * np.pi / segments)
    rings = np.stack([inner[:, :1] * np.cos(theta), np.broadcast_to(inner[:, 1:], (len(inner), segments)),
                      inner[:, :1] * np.sin(theta)], axis=-1).reshape(-1, 3)
    top = len(rings) + 1
    vertices = np.concatenate([[[0.0, profile[0, 1], 0.0]], rings, [[0.0, profile[-1, 1], 0.0]]])
    j = np.arange(segments)
    nxt = (j + 1) % segments
    last = 1 + (len(inner) - 1) * segments
    faces = np.concatenate([
        np.stack([np.zeros_like(j), 1 + j, 1 + nxt], axis=1),                 # bottom fan
        grid_faces(len(inner), segments, wrap=True) + 1,                      # bands
        np.stack([last + j, np.full_like(j, top), last + nxt], axis=1),      # top fan
    ])
    return vertices, faces


def resample_polyline(points: np.ndarray, segments: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Split each piece of a polyline evenly so the whole has exactly ``segments`` pieces.

    Every input point is kept; pieces get subdivisions in proportion to ``length * weight``
    (largest remainder), at least one each.

    Parameters
    ----------
    points : (k, d) float
    segments : int
        At least ``k - 1``.
    weights : (k - 1,) float, optional
        Non-negative importance of each piece (default 1).

    Returns
    -------
    (segments + 1, d) float
    """
    points = np.asarray(points, dtype=np.float64)
    pieces = len(points) - 1
    if segments < pieces:
        raise ValueError(f"segments ({segments}) must be >= the polyline's {pieces} pieces")
    share = np.linalg.norm(np.diff(points, axis=0), axis=1)
    if weights is not None:
        share = share * np.asarray(weights, dtype=np.float64)
    ideal = segments * share / share.sum() if share.sum() > 0 else np.full(pieces, segments / pieces)
    counts = np.maximum(1, np.floor(ideal)).astype(np.int64)
    while counts.sum() > segments:  # only when many pieces were forced up to one
        counts[np.argmax(np.where(counts > 1, counts - ideal, -np.inf))] -= 1
    short = segments - counts.sum()
    counts[np.argsort(counts - ideal, kind="stable")[:short]] += 1
    piece = np.repeat(np.arange(pieces), counts)
    step = ragged_arange(counts)
    t = (step / counts[piece])[:, None]
    inner = points[piece] * (1 - t) + points[piece + 1] * t
    return np.concatenate([inner, points[-1:]])


# (radius, y) from the bottom centre out, over both basins, to the finial's tip. The lower
# basin is 1 wide (radius) and 0.3 high; its wall top carries a bead that overhangs the
# outer wall; the upper bowl's underside flares from the column to a drip lip at r = 0.58.
_FOUNTAIN_PROFILE = np.array([
    [0.00, 0.00], [1.00, 0.00],                                    # base
    [1.00, 0.22], [1.03, 0.25], [1.03, 0.29], [0.99, 0.30],        # outer wall, bead
    [0.93, 0.30], [0.92, 0.10], [0.20, 0.08],                      # inner wall, floor
    [0.20, 0.16], [0.12, 0.20], [0.10, 0.24],                      # plinth
    [0.09, 0.62], [0.12, 0.66],                                    # column, collar
    [0.14, 0.70], [0.25, 0.78], [0.40, 0.88], [0.52, 0.95],        # bowl underside
    [0.56, 0.97], [0.58, 1.00], [0.57, 1.03], [0.53, 1.04],        # drip lip, rim
    [0.50, 1.02], [0.42, 0.96], [0.28, 0.88], [0.12, 0.84],        # bowl inside
    [0.05, 0.84], [0.04, 1.00], [0.07, 1.06], [0.08, 1.10],        # finial
    [0.06, 1.15], [0.00, 1.17],
])
# The flat underside gets no extra rings: nothing happens there.
_FOUNTAIN_WEIGHTS = np.r_[0.0, np.ones(len(_FOUNTAIN_PROFILE) - 2)]
