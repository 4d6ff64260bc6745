"""Sliver clean-up: vertices closer than a tolerance merged, the faces they collapse dropped."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..geometry import face_any
from .fuse_kernel import compacted


def sliver_candidates(vertices: np.ndarray, fields, tol: float) -> np.ndarray:
    """``(n,) bool``: the vertices where slivers and needles can be, for `clean_slivers`'
    ``near``: those on no lattice edge of any of ``fields`` (a boolean union cut them) and
    those within ``4 tol`` of a lattice corner.

    Marching cubes puts every vertex on a lattice edge, and its samples are pushed off the
    level (`icefarm.metaballs.march`), so its own faces are never that thin; the union's cuts
    are. On row c of Table 2, the bunny, the fountain, the bench and the 3 m house, every
    sliver and needle of the fused mesh touched one of these (1 to 10 % of the vertices).

    Parameters
    ----------
    vertices : (n, 3) float
        A fused mesh's vertices, meters, before anything moved them.
    fields : sequence of `icefarm.metaballs.Field`
        The fields it was marched from (their origins and voxels).
    tol : float
        `collapse_slivers`' tolerance, meters.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    on_edge = np.zeros(len(vertices), dtype=bool)
    cornered = np.zeros(len(vertices), dtype=bool)
    for field in fields:
        c = (vertices - field.origin) / field.voxel
        off = np.abs(c - np.rint(c))  # off a lattice plane, per axis
        # On two lattice planes, and how far off the third (column by column: numpy sorts
        # and reduces rows of three several times slower).
        x, y, z = (off[:, k] < 1e-6 for k in range(3))
        edge = (x & y) | (x & z) | (y & z)
        on_edge |= edge
        cornered |= edge & (np.maximum(np.maximum(off[:, 0], off[:, 1]), off[:, 2]) < 4.0 * tol / field.voxel)
    return ~on_edge | cornered


def clean_slivers(vertices: np.ndarray, faces: np.ndarray, tol: float, near: np.ndarray | None = None):
    """`collapse_slivers`, then `flip_needles` on what it left, both on the faces at
    ``near`` vertices only (all faces when None).

    Returns
    -------
    vertices : (k, 3) float64
    faces : (j, 3) int64
    kept : (k,) int64
        The input vertex each output vertex is (a merged group keeps its lowest): index
        per-vertex values with it to keep them with their vertices.
    """
    vertices, faces, kept = _collapse(vertices, faces, tol, near)
    if near is not None and kept is not None:
        near = np.asarray(near, dtype=bool)[kept]
    faces = flip_needles(vertices, faces, tol, near=near)
    return vertices, faces, np.arange(len(vertices)) if kept is None else np.flatnonzero(kept)


def collapse_slivers(vertices: np.ndarray, faces: np.ndarray, tol: float, near: np.ndarray | None = None):
    """Merge the ends of edges shorter than ``tol`` (and vertices within ``tol`` of those)
    and drop the faces that collapse.

    A boolean union cuts along the other surface's faces, and marching cubes can land two
    vertices a hair apart: both leave faces of next to no area (edges of 1e-8 m), which
    renderers and exporters treat as broken. Merging them is an edge collapse: the mesh
    stays closed, so the result is kept only where it still has every edge shared by
    exactly two faces; otherwise the input comes back unchanged.

    Parameters
    ----------
    vertices : (n, 3) float
        Meters.
    faces : (m, 3) int
    tol : float
        Meters; a thousandth of a voxel is ample.
    near : (n,) bool, optional
        Look only at the faces with a vertex here (the ones an edit moved).

    Returns
    -------
    vertices : (k, 3) float64
    faces : (j, 3) int64
    """
    vertices, faces, _ = _collapse(vertices, faces, tol, near)
    return vertices, faces


def _collapse(vertices, faces, tol, near):
    """`collapse_slivers`, and which input vertices it kept ((n,) bool; None: all, as they were)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return vertices, faces, None
    # Vertices a hair apart end an edge that short: only those ends are searched (a tree of
    # every vertex of a million-face mesh would take most of the time).
    # (np.compress: a boolean index copies rows of a face array about 4 times slower)
    look = faces if near is None else np.compress(face_any(np.asarray(near, dtype=bool), faces), faces, axis=0)
    a, b, c = vertices[look[:, 0]], vertices[look[:, 1]], vertices[look[:, 2]]
    edges = [(0, 1, b - a), (1, 2, c - b), (2, 0, a - c)]
    ends = np.unique(np.concatenate([look[(d * d).sum(axis=1) < tol * tol][:, [i, j]].ravel() for i, j, d in edges]))
    if len(ends) == 0:
        return vertices, faces, None
    pairs = ends[cKDTree(vertices[ends]).query_pairs(tol, output_type="ndarray")].reshape(-1, 2)
    if len(pairs) == 0:
        return vertices, faces, None
    n = len(vertices)
    # Groups of close vertices, found among the few that are; the lowest index stands for each.
    nodes, inverse = np.unique(pairs, return_inverse=True)
    inverse = inverse.reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (inverse[:, 0], inverse[:, 1])), shape=(len(nodes),) * 2)
    _, group = connected_components(graph, directed=False)
    lowest = np.full(group.max() + 1, n, dtype=np.int64)
    np.minimum.at(lowest, group, nodes)
    rep = np.arange(n)
    rep[nodes] = lowest[group]
    touched = np.zeros(n, dtype=bool)
    touched[nodes] = True
    # Only faces at a merged vertex change, and every edge at one lies in such faces only,
    # so the collapse is done and checked on those faces alone.
    hit = face_any(touched, faces)
    merged = rep[np.compress(hit, faces, axis=0)]
    keep = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 0] != merged[:, 2])
    merged = merged[keep]
    # A collapse can leave a face and its mirror image back to back: drop both.
    _, inverse, count = np.unique(np.sort(merged, axis=1), axis=0, return_inverse=True, return_counts=True)
    merged = merged[count[inverse.reshape(-1)] == 1]
    if not _closed_at(merged, np.unique(rep[nodes])):
        return vertices, faces, None
    out, kept = compacted(np.concatenate([np.compress(~hit, faces, axis=0), merged]), n)
    used = np.zeros(n, dtype=bool)
    used[kept] = True
    return vertices[kept], out, used


def _closed_at(faces: np.ndarray, at: np.ndarray) -> bool:
    """Every directed edge of ``faces`` with an end in ``at`` appears once and its reverse
    once: closed and consistently wound there."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = edges[np.isin(edges, at).any(axis=1)]
    fwd = np.unique(edges, axis=0, return_counts=True)
    if (fwd[1] != 1).any():
        return False
    rev = np.unique(edges[:, ::-1], axis=0)
    return len(rev) == len(fwd[0]) and np.array_equal(rev, fwd[0])


def flip_needles(vertices: np.ndarray, faces: np.ndarray, height: float, near: np.ndarray | None = None):
    """Flip the longest edge of each face flatter than ``height`` (a needle: one corner on
    the opposite edge, no short edge to collapse) with the face across it.

    Faces ``(u, v, w)`` and ``(v, u, x)`` become ``(u, x, w)`` and ``(x, v, w)``: the same
    surface, closed and wound as before. A flip that would make an edge the mesh already
    has, or a new needle, is skipped.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    height : float
        Meters: a face's least height under this makes it a needle.
    near : (n,) bool, optional
        Look only at the faces with a vertex here (the ones an edit moved).

    Returns
    -------
    (m, 3) int64
        The faces (the same array when there is no needle).
    """
    faces = np.asarray(faces, dtype=np.int64)
    if near is None:
        needles = np.flatnonzero(_flat(vertices, faces, height))
    else:
        candidates = np.flatnonzero(face_any(np.asarray(near, dtype=bool), faces))
        needles = candidates[_flat(vertices, faces[candidates], height)]
    if len(needles) == 0:
        return faces
    faces = faces.copy()
    n = len(vertices)
    # Every edge a flip reads or makes joins two vertices of the needles' faces or of their
    # neighbours across an edge, so the lookup holds the faces at those vertices only (an
    # argsort of every edge of a million-face mesh would take most of the time).
    near = np.zeros(n, dtype=bool)
    near[faces[needles]] = True
    local = np.flatnonzero(face_any(near, faces))
    near[faces[local]] = True
    local = np.flatnonzero(face_any(near, faces))
    sub = faces[local]
    m = len(local)
    keys = np.concatenate([sub[:, 0] * n + sub[:, 1], sub[:, 1] * n + sub[:, 2], sub[:, 2] * n + sub[:, 0]])
    order = np.argsort(keys)
    sorted_keys = keys[order]
    changed: dict[int, int | None] = {}  # directed edges the flips made (face) or unmade (None)

    def owner(a: int, b: int) -> int | None:
        key = a * n + b
        if key in changed:
            return changed[key]
        i = int(np.searchsorted(sorted_keys, key))
        return int(local[order[i] % m]) if i < len(sorted_keys) and sorted_keys[i] == key else None

    for f in needles:
        u, v, w = _longest_edge_first(vertices, faces[f])
        g = owner(v, u)
        if g is None or g == f:
            continue
        x = int(next(c for c in faces[g] if c != u and c != v))
        if x == w or owner(x, w) is not None or owner(w, x) is not None:
            continue
        new = np.array([[u, x, w], [x, v, w]])
        if (_heights(vertices, new) < height).any():
            continue
        for face in (faces[f], faces[g]):
            for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
                changed[int(a) * n + int(b)] = None
        faces[f], faces[g] = new
        for i in (f, g):
            for a, b in ((faces[i][0], faces[i][1]), (faces[i][1], faces[i][2]), (faces[i][2], faces[i][0])):
                changed[int(a) * n + int(b)] = int(i)
    return faces


def _flat(vertices: np.ndarray, faces: np.ndarray, height: float) -> np.ndarray:
    """(m,) bool: faces whose least height is under ``height`` (`_heights` < height, without
    its square roots and rolls, which take most of its time on a million faces)."""
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    ab, bc, ca = b - a, c - b, a - c
    longest = np.maximum(np.maximum((ab * ab).sum(axis=1), (bc * bc).sum(axis=1)), (ca * ca).sum(axis=1))
    cx = ab[:, 1] * ca[:, 2] - ab[:, 2] * ca[:, 1]
    cy = ab[:, 2] * ca[:, 0] - ab[:, 0] * ca[:, 2]
    cz = ab[:, 0] * ca[:, 1] - ab[:, 1] * ca[:, 0]
    return cx * cx + cy * cy + cz * cz < height * height * longest


def _heights(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Least height of each triangle (twice its area over its longest edge), meters."""
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    double_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return double_area / np.maximum(edges, 1e-300)


def _longest_edge_first(vertices, face):
    """``(u, v, w)``: the face rolled so that ``u -> v`` is its longest edge."""
    tri = np.asarray(vertices)[face]
    lengths = np.linalg.norm(tri[[1, 2, 0]] - tri, axis=1)  # edge i runs from corner i to i + 1
    i = int(np.argmax(lengths))
    return int(face[i]), int(face[(i + 1) % 3]), int(face[(i + 2) % 3])
