"""How a fringe of icicles hangs, measured on the ice mesh: free of its neighbours down its
length, and ragged in length from one icicle to the next.

* **Free** (`hangs_free`): the ice cut by the level plane through a trunk's half length. A
  trunk hangs free when the loop of the section around its axis is closed and holds no other
  icicle's axis: neighbours that fuse into a sheet share one loop, and one fused to a wall
  has none that closes near it. Real fringes fuse near their roots, rarely down their length.
* **Ragged** (`length_contrast`): for each icicle, the longest of itself and its
  `NEIGHBOURS` nearest roots within `REACH` over the shortest. An even fringe reads about
  1.5; photographs of eaves and wires, 2.5 and more (a few long icicles, short ones between).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ...geometry import arc_lengths, perpendicular_basis, unit
from ..trajectories import TrajectoryResult
from ..trajectory_stats import SHAPE_MIN_LENGTH

# Trunks this long and more are checked for hanging free (meters).
FREE_MIN_LENGTH = SHAPE_MIN_LENGTH
# Half-width of the window around a trunk's axis whose faces are cut (meters), at least
# WINDOW, and WINDOW_PER_LENGTH of the trunk's length: a metre-long eave icicle is 10 cm
# across at half its length, and a loop the window cuts reads as fused.
WINDOW = 0.06
WINDOW_PER_LENGTH = 0.12
# At most this many trunks are cut, evenly over the icicles.
MAX_CUT = 400
# Roots an icicle's length is compared with, and how far they may lie (meters).
NEIGHBOURS = 4
REACH = 0.10
# Section end points closer than this (meters) are one.
WELD = 1e-7


@dataclass(frozen=True)
class FringeFigures:
    """How the fringe hangs (`fringe_figures`).

    Attributes
    ----------
    free_share : float
        Share of the trunks of `FREE_MIN_LENGTH` and more that hang free at half their
        length (nan: none that long).
    checked : int
        Trunks cut for it.
    length_contrast : float
        Median over icicles of the longest of each and its nearest roots over the
        shortest (nan: no icicle has a neighbour within `REACH`).
    """

    free_share: float
    checked: int
    length_contrast: float


def trunk_lengths(traj: TrajectoryResult) -> tuple[np.ndarray, np.ndarray]:
    """Each icicle's trunk: its index among the branches and its arc length, meters.

    Returns
    -------
    trunks : (i,) int
        Branches with no parent and at least two points.
    lengths : (i,) float
    """
    offsets = np.asarray(traj.branch_offsets)
    counts = np.diff(offsets)
    trunks = np.flatnonzero((np.asarray(traj.branch_parent) < 0) & (counts > 1))
    x, _ = arc_lengths(traj.points, offsets)
    return trunks, x[offsets[trunks + 1] - 1]


def length_contrast(roots: np.ndarray, lengths: np.ndarray, neighbours: int = NEIGHBOURS,
                    reach: float = REACH) -> float:
    """Median over icicles of max / min length among each and its ``neighbours`` nearest
    ``roots`` (k, 3) within ``reach`` meters; icicles with none that close are left out."""
    lengths = np.asarray(lengths, dtype=np.float64)
    if len(lengths) < 2:
        return float("nan")
    k = min(neighbours + 1, len(lengths))
    distance, index = cKDTree(roots).query(roots, k=k, distance_upper_bound=reach)
    near = np.isfinite(distance)
    near[:, 0] = True  # itself
    has = near[:, 1:].any(axis=1)
    if not has.any():
        return float("nan")
    values = np.where(near, lengths[np.minimum(index, len(lengths) - 1)], np.nan)
    ratio = np.nanmax(values, axis=1) / np.maximum(np.nanmin(values, axis=1), 1e-9)
    return float(np.median(ratio[has]))


def _loops(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The connected pieces of a section's ``segments`` (m, 2, 2): each segment's piece, and
    whether each piece closes (every end point shared by exactly two segments)."""
    ends = np.round(segments.reshape(-1, 2) / WELD).astype(np.int64)
    _, node = np.unique(ends, axis=0, return_inverse=True)
    node = node.reshape(-1, 2)
    n = int(node.max()) + 1
    graph = coo_matrix((np.ones(len(node)), (node[:, 0], node[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    degree = np.bincount(node.ravel(), minlength=n)
    piece = label[node[:, 0]]
    open_piece = np.zeros(label.max() + 1, dtype=bool)
    open_piece[label[degree != 2]] = True
    return piece, ~open_piece


def _enclosing(segments: np.ndarray, piece: np.ndarray, pieces: int, point: np.ndarray) -> np.ndarray:
    """``(pieces,) bool``: the pieces an even-odd ray from ``point`` (2,) crosses an odd number of times."""
    a, b = segments[:, 0] - point, segments[:, 1] - point
    straddle = (a[:, 1] > 0) != (b[:, 1] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = a[:, 0] + (b[:, 0] - a[:, 0]) * (-a[:, 1]) / (b[:, 1] - a[:, 1])
    crossing = straddle & (x > 0)
    return np.bincount(piece[crossing], minlength=pieces) % 2 == 1


def _half_point(points: np.ndarray, x: np.ndarray, offsets: np.ndarray, branch: int) -> np.ndarray:
    """(3,) the point of ``branch``'s axis at half its length (``x``: arc lengths)."""
    start, stop = offsets[branch], offsets[branch + 1]
    return np.array([np.interp(0.5 * x[stop - 1], x[start:stop], points[start:stop, k]) for k in range(3)])


def _cut_near(faces: np.ndarray, vertices: np.ndarray, candidates: np.ndarray, high: np.ndarray, level: float,
              centre: np.ndarray, reach: float) -> np.ndarray:
    """The ``candidates`` (faces whose lowest point is at most ``level``) that reach up to
    ``level`` and whose centroid lies within ``reach`` of ``centre`` (3,)."""
    near = candidates[high[candidates] >= level]
    f = faces[near]
    d2 = np.zeros(len(near))
    for k in range(3):
        d2 += ((vertices[f[:, 0], k] + vertices[f[:, 1], k] + vertices[f[:, 2], k]) / 3.0 - centre[k]) ** 2
    return near[d2 <= reach * reach]


def hangs_free(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult, gravity,
               min_length: float = FREE_MIN_LENGTH, window: float = WINDOW,
               max_cut: int = MAX_CUT) -> tuple[np.ndarray, np.ndarray]:
    """Which trunks of ``min_length`` and more hang free: their level section at half their
    length is a closed loop of their own (module docstring).

    Parameters
    ----------
    vertices : (n, 3) float
        The ice mesh, meters.
    faces : (f, 3) int
    traj : TrajectoryResult
        The icicles' axes.
    gravity : (3,) float

    Returns
    -------
    trunks : (c,) int
        Branches cut: the trunks that long, at most ``max_cut`` of them, evenly spread.
    free : (c,) bool
    """
    g = unit(np.asarray(gravity, dtype=np.float64))
    trunks, lengths = trunk_lengths(traj)
    long = trunks[lengths >= min_length]
    if len(long) == 0 or len(faces) == 0:
        return long, np.zeros(len(long), dtype=bool)
    if len(long) > max_cut:
        long = long[np.linspace(0, len(long) - 1, max_cut).round().astype(np.int64)]
    offsets = np.asarray(traj.branch_offsets)
    points = np.asarray(traj.points, dtype=np.float64)
    x, _ = arc_lengths(points, offsets)
    # Every axis segment, with its icicle, to find the other icicles crossing a section.
    branch_of_point = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    segment = np.flatnonzero(np.diff(branch_of_point) == 0)
    seg_a, seg_b = points[segment], points[segment + 1]
    seg_icicle = np.asarray(traj.branch_icicle)[branch_of_point[segment]]
    seg_tree = cKDTree(0.5 * (seg_a + seg_b))
    u, v = perpendicular_basis(g)
    height = vertices @ -g
    # The faces a level cuts, from faces sorted by their lowest point: no tree over the
    # mesh's faces (the 1.5 m car's 2.3 M: 1.6 s to build).
    h0, h1, h2 = (height[faces[:, k]] for k in range(3))
    low, high = np.minimum(np.minimum(h0, h1), h2), np.maximum(np.maximum(h0, h1), h2)
    by_low = np.argsort(low, kind="stable")
    low_sorted, tallest = low[by_low], float((high - low).max())
    face_reach = window + float(np.sqrt(((vertices[faces[:, 0]] - vertices[faces[:, 1]]) ** 2).sum(axis=1)).max())
    free = np.zeros(len(long), dtype=bool)
    for n, trunk in enumerate(long):
        half = 0.5 * x[offsets[trunk + 1] - 1]
        centre = _half_point(points, x, offsets, trunk)
        level = float(centre @ -g)
        own_window = max(window, WINDOW_PER_LENGTH * 2.0 * half)
        near = _cut_near(faces, vertices, by_low[np.searchsorted(low_sorted, level - tallest):
                                                    np.searchsorted(low_sorted, level, side="right")],
                         high, level, centre, face_reach - window + own_window)
        if len(near) == 0:
            continue
        used, local = np.unique(faces[near], return_inverse=True)
        piece_mesh = trimesh.Trimesh(vertices[used], local.reshape(-1, 3), process=False)
        cut = trimesh.intersections.mesh_plane(piece_mesh, -g, centre)
        if len(cut) == 0:
            continue
        flat = np.stack([cut @ u, cut @ v], axis=-1)
        piece, closed = _loops(flat)
        # Only closed loops enclose anything: a piece the window cut (a sheet running on, a
        # neighbour's edge) is open, and the ray's parity through it means nothing.
        inside = _enclosing(flat, piece, len(closed), np.array([centre @ u, centre @ v])) & closed
        around = np.flatnonzero(inside)
        if len(around) == 0:
            continue
        own = around[np.argmin([np.ptp(flat[piece == k].reshape(-1, 2), axis=0).prod() for k in around])]
        # Other icicles whose axes cross this level inside the loop share it: a sheet.
        others = np.asarray(seg_tree.query_ball_point(centre, own_window), dtype=np.int64)
        others = others[seg_icicle[others] != traj.branch_icicle[trunk]]
        ha, hb = seg_a[others] @ -g, seg_b[others] @ -g
        crosses = others[(np.minimum(ha, hb) <= level) & (np.maximum(ha, hb) > level)]
        shared = False
        for s in crosses:
            a, b = seg_a[s], seg_b[s]
            t = (level - a @ -g) / ((b - a) @ -g)
            p = a + t * (b - a)
            if _enclosing(flat, piece, len(closed), np.array([p @ u, p @ v]))[own]:
                shared = True
                break
        free[n] = not shared
    return long, free


def fringe_figures(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult, gravity) -> FringeFigures:
    """`FringeFigures` of the icicles ``traj`` on the ice mesh (``vertices`` (n, 3) in
    meters, ``faces`` (f, 3))."""
    checked, free = hangs_free(vertices, faces, traj, gravity)
    share = float(free.mean()) if len(free) else float("nan")
    trunks, lengths = trunk_lengths(traj)
    roots = np.asarray(traj.points)[np.asarray(traj.branch_offsets)[trunks]]
    return FringeFigures(free_share=share, checked=len(checked), length_contrast=length_contrast(roots, lengths))
