"""The separate parts of a mesh: its connected pieces grouped by the gaps between them.

A proxy's lengths (`icefarm.stages.proxy`: the wrap's alpha and offset, the remesh's edge)
are fractions of a bounding-box diagonal. Over objects far apart (two 30 cm cubes 3 m, or
300 m, apart) the whole mesh's diagonal is that of the empty space between them: each
cube would be wrapped with the offset of a 300 m object into a 1.5 m blob that grows 30 icicles,
where the cube alone grows none. Each part is built at its own scale instead.

Pieces (connected by shared edges) belong to one part when their bounding boxes, grown by
``gap`` times the diagonal of the group they are in, overlap; a group that splits so is
split again at each piece of its own scale, until no group splits. With ``gap`` the wrap's
alpha, a part's own wrap would bridge nothing between two parts that the joint wrap did
not leave apart too (boxes lie no farther apart than the surfaces in them), and pieces
that touch or pass through each other (a teapot's lid, a chair's legs, a soup's triangles)
stay one part.
"""

from __future__ import annotations

import numpy as np
import trimesh


def piece_boxes(vertices: np.ndarray, faces: np.ndarray, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of each piece.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions.
    faces : (m, 3) int
        Triangles.
    pieces : (m,) int
        Piece of each face, ``0 .. k - 1``, each used.

    Returns
    -------
    low, high : (k, 3) float
        Corners of each piece's box.
    """
    triangles = np.asarray(vertices, dtype=np.float64)[faces]
    order = np.argsort(pieces, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(pieces[order]) > 0])
    low = np.minimum.reduceat(triangles.min(axis=1)[order], starts)
    high = np.maximum.reduceat(triangles.max(axis=1)[order], starts)
    return low, high


def _overlapping(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``(k,) int``: connected groups of the boxes ``low``-``high`` ``(k, 3)`` that overlap."""
    if len(low) == 1:
        return np.zeros(1, dtype=np.int64)
    tree = trimesh.util.bounds_tree(np.column_stack((low, high)))
    ids, counts = tree.intersection_v(low, high)
    edges = np.column_stack((np.repeat(np.arange(len(low)), counts.astype(np.int64)), ids.astype(np.int64)))
    return trimesh.graph.connected_component_labels(edges, node_count=len(low))


def group_pieces(low: np.ndarray, high: np.ndarray, *, gap: float) -> np.ndarray:
    """Group pieces into parts by the gaps between their boxes, each part at its own scale.

    Parameters
    ----------
    low, high : (k, 3) float
        Corners of each piece's bounding box (`piece_boxes`).
    gap : float
        Boxes nearer than this fraction of the diagonal of the group they are in are one
        part (the wrap's alpha).

    Returns
    -------
    (k,) int
        Part of each piece, ``0 .. parts - 1``; a single part is all zeros.
    """
    labels = np.zeros(len(low), dtype=np.int64)
    parts, pending = 0, [np.arange(len(low))]
    while pending:
        group = pending.pop()
        lo, hi = low[group], high[group]
        grow = 0.5 * gap * float(np.linalg.norm(hi.max(axis=0) - lo.min(axis=0)))
        split = _overlapping(lo - grow, hi + grow)
        if split.max() == 0:
            labels[group] = parts
            parts += 1
            continue
        pending.extend(group[split == label] for label in range(int(split.max()) + 1))
    _, first = np.unique(labels, return_index=True)  # numbered in the order of their first piece
    return np.argsort(np.argsort(first))[labels]
