"""Small geometric helpers shared by the stages: frames, face normals and volume, sampling,
chain sums, ranges within groups laid end to end, arc lengths of polylines laid end to end."""

from __future__ import annotations

import numpy as np
import trimesh

# `stable_order` counts keys into slots when they span at most this many times their number.
COUNTING_SPAN = 4


def unit(vectors: np.ndarray) -> np.ndarray:
    """Vectors ``(..., 3)`` scaled to unit length (zero vectors stay zero)."""
    vectors = np.asarray(vectors, dtype=np.float64)
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norm, out=np.zeros_like(vectors), where=norm > 0)


def world_frame(gravity) -> np.ndarray:
    """Rows ``right, up, front`` ``(3, 3)``: an orthonormal right-handed frame with up = -gravity.

    ``front`` is the first of +Z, -Y, +X that is not close to ``up``: Y-up assets face +Z
    and Z-up ones -Y, as their authors expect (cameras at azimuth 0 and the default wind
    come from there).

    Raises
    ------
    ValueError
        Gravity is zero or not finite.
    """
    g = np.asarray(gravity, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(g)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"gravity must be a non-zero finite vector, got {gravity!r}")
    up = -g / norm
    for ref in ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)):
        ref = np.asarray(ref)
        if abs(ref @ up) < 0.9:
            break
    front = ref - (ref @ up) * up
    front /= np.linalg.norm(front)
    return np.stack([np.cross(up, front), up, front])


def perpendicular_basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(3,)`` that complete ``direction`` to a right-handed frame."""
    d = unit(direction)
    helper = np.eye(3)[np.argmin(np.abs(d))]
    u = unit(np.cross(d, helper))
    return u, np.cross(d, u)


def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(e1 x e2)`` per face ``(m, 3)``: the normal scaled by twice the face area (m^2).

    `trimesh.triangles.cross` of ``vertices[faces]`` (`cross`: np.cross is slower on millions
    of rows), faster than trimesh's on a million faces.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    v0 = vertices[faces[:, 0]]
    return cross(vertices[faces[:, 1]] - v0, vertices[faces[:, 2]] - v0)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of rows ``(k, 3)``, written out: the same numbers (each component the
    same two products and difference), in half its time on 400 k rows (9 against 21 ms)."""
    a, b = np.asarray(a), np.asarray(b)
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def squared_lengths(vectors: np.ndarray) -> np.ndarray:
    """``(x^2 + y^2) + z^2`` of rows ``(..., 3)``: what ``np.linalg.norm(v, axis=-1) ** 2``
    sums, in that order (so their square roots are its norms), without its reduction over
    an axis of three, which takes most of its time."""
    v = np.asarray(vectors)
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2]


def face_any(mask: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(m,) bool``: the faces ``(m, 3)`` (or edges ``(m, 2)``) with a corner where ``mask``
    ``(n,) bool`` is set.

    ``mask[faces].any(axis=1)`` column by column: numpy reduces rows of three 6 times slower
    (measured on the 731 k faces of Table 2's dragon ice).
    """
    faces = np.asarray(faces)
    out = mask[faces[:, 0]].copy()
    for k in range(1, faces.shape[1]):
        out |= mask[faces[:, k]]
    return out


def within_box(points: np.ndarray, lo, hi) -> np.ndarray:
    """``(n,) bool``: the ``points`` ``(n, k)`` with every coordinate in ``[lo, hi]`` (``(k,)``
    each): ``((points >= lo) & (points <= hi)).all(axis=1)`` column by column, as `face_any`
    reduces (on the car's 1.2 M ice vertices 18 ms against 48 ms)."""
    points = np.asarray(points)
    out = np.ones(len(points), dtype=bool)
    for k in range(points.shape[1]):
        out &= (points[:, k] >= lo[k]) & (points[:, k] <= hi[k])
    return out


def face_all(mask: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(m,) bool``: the faces ``(m, 3)`` with all their corners where ``mask`` ``(n,) bool``
    is set (``mask[faces].all(axis=1)``, as fast as `face_any`)."""
    faces = np.asarray(faces)
    out = mask[faces[:, 0]].copy()
    for k in range(1, faces.shape[1]):
        out &= mask[faces[:, k]]
    return out


def face_count(mask: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(m,) uint8``: how many corners of each face ``(m, 3)`` ``mask`` ``(n,) bool`` sets
    (``mask[faces].sum(axis=1)``, as fast as `face_any`)."""
    faces = np.asarray(faces)
    m = np.asarray(mask, dtype=bool).view(np.uint8)
    out = m[faces[:, 0]].copy()
    for k in range(1, faces.shape[1]):
        out += m[faces[:, k]]
    return out


def signed_volume(vertices: np.ndarray, faces: np.ndarray, *,
                  labels: np.ndarray | None = None) -> float | np.ndarray:
    """Signed volume (m^3) of a closed mesh, or of each of its pieces: negative when wound inwards.

    The volume of `trimesh.triangles.mass_properties`, without its centre of mass and
    inertia integrals, which take most of its time (and of ``mesh.volume``'s).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    labels : (m,) int, optional
        Piece ``0 .. k - 1`` of each face.

    Returns
    -------
    float, or (k,) float with ``labels``: the volume of each piece.
    """
    cross = face_cross(vertices, faces)
    v0 = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)[:, 0]]
    if labels is None:
        return float(np.einsum("ij,ij->", v0, cross) / 6.0)  # v0 . (v1 x v2) = v0 . (e1 x e2)
    return np.bincount(labels, weights=np.einsum("ij,ij->i", v0, cross) / 6.0)


def random_barycentric(count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, 3)`` barycentric coordinates of uniform random points in a triangle.

    ``(1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2)`` from two uniform draws (Osada et al.
    2002, "Shape distributions", Section 4.2). `trimesh.sample.sample_surface` folds its
    draws into the triangle instead: as uniform, but other points from the same generator,
    and `sample_faces`' points are pinned by tests.
    """
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    return np.column_stack([1 - s, s * (1 - r2), s * r2])


def sample_faces(mesh: trimesh.Trimesh, faces: np.ndarray, count: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform random points over a subset of faces, area-weighted.

    Picks the faces `trimesh.sample.sample_surface` picks from ``rng`` with ``face_weight``
    the areas of a sorted ``faces`` (zero elsewhere), without its pass over every face of
    the mesh, which costs most when few points are drawn on a large mesh. Points in a
    face: `random_barycentric`.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    faces : (m,) int
        Candidate faces; empty or zero-area gives no points.
    count : int
        Points wanted.
    rng : numpy.random.Generator

    Returns
    -------
    points : (count, 3) float
    face : (count,) int
        Face of each point.
    bary : (count, 3) float
        Barycentric coordinates of each point in its face.
    """
    faces = np.asarray(faces, dtype=np.int64)
    areas = mesh.area_faces[faces] if len(faces) else np.zeros(0)
    if count <= 0 or areas.sum() <= 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    face = faces[rng.choice(len(faces), size=count, p=areas / areas.sum())]
    bary = random_barycentric(count, rng)
    points = np.einsum("ij,ijk->ik", bary, mesh.vertices[mesh.faces[face]])
    return points, face, bary


def chain_sums(parent: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum ``values`` along each vertex's chain of parents up to its root.

    Pointer doubling: every chain advances at once, ``log2(longest chain)`` passes.

    Parameters
    ----------
    parent : (n,) int
        Next vertex of each chain; a root is its own parent. Chains must be acyclic.
    values : (n, k) float
        Value added when stepping from a vertex to its parent (ignored at roots).

    Returns
    -------
    sums : (n, k) float
        Sum of ``values`` from each vertex up to, excluding, its root.
    root : (n,) int
        Root reached from each vertex.
    """
    parent = np.asarray(parent, dtype=np.int64)
    acc = np.array(values, dtype=np.float64, copy=True)
    roots = parent == np.arange(len(parent))
    acc[roots] = 0.0
    ptr = parent.copy()
    while True:
        moving = ptr[ptr] != ptr
        if not moving.any():
            break
        acc += acc[ptr]
        ptr = ptr[ptr]
    return acc, ptr


def stable_order(keys: np.ndarray) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` for integer ``keys`` ``(n,)``, faster.

    NumPy's stable sort of int64 is a merge sort: 0.20-0.23 s on 1.3 M random keys (a car's
    face adjacency, both ways). Keys from a range at most `COUNTING_SPAN` times their number
    (face or vertex indices, as every caller's are) take a compiled counting sort
    (`icefarm.counting_sort`); others a quicksort of ``key * n + position``, unique keys
    whose order is the stable one (0.06 s there); keys whose products would not fit in int64
    the merge sort.
    """
    keys = np.asarray(keys)
    n = len(keys)
    if n == 0 or not np.issubdtype(keys.dtype, np.integer):
        return np.argsort(keys, kind="stable")
    low, high = int(keys.min()), int(keys.max())
    if high - low < COUNTING_SPAN * n:
        from .counting_sort import counting_order

        return counting_order(np.ascontiguousarray(keys, dtype=np.int64), low, high - low + 1)
    if low < 0 or (high + 1) * n >= 2**62:
        return np.argsort(keys, kind="stable")
    return np.argsort(keys.astype(np.int64) * n + np.arange(n, dtype=np.int64))


def ragged_arange(counts: np.ndarray, dtype=np.int64) -> np.ndarray:
    """Each element's index within its group, for groups laid end to end.

    Parameters
    ----------
    counts : (g,) int
        Elements of each group (0 for an empty one).
    dtype : numpy integer type
        Of the result (``np.int32`` halves the memory of a long one).

    Returns
    -------
    (counts.sum(),) int
        ``0, 1, ..., counts[0] - 1, 0, 1, ..., counts[1] - 1, ...``; with the group of
        each element, ``np.repeat(np.arange(g), counts)``, it addresses ragged rows.

    Examples
    --------
    >>> ragged_arange(np.array([3, 0, 2]))
    array([0, 1, 2, 0, 1])
    """
    counts = np.asarray(counts)
    starts = np.cumsum(counts) - counts
    return np.arange(int(counts.sum()), dtype=dtype) - np.repeat(starts.astype(dtype, copy=False), counts)


def arc_lengths(points: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths along polylines laid end to end (a `TrajectoryResult`'s branches).

    Parameters
    ----------
    points : (p, 3) float
        The polylines' points, one polyline after the other, meters.
    offsets : (b + 1,) int
        Polyline ``i`` is ``points[offsets[i]:offsets[i + 1]]`` (it may be empty).

    Returns
    -------
    x : (p,) float
        Each point's distance from its polyline's first point along the polyline, meters.
    lengths : (b,) float
        Each polyline's length, meters (0 for an empty one or a single point).

    Notes
    -----
    Differences of one running sum over all the polylines: a polyline's figures depend, in
    their last bits, on the polylines before it.
    """
    pts = np.asarray(points, dtype=np.float64)
    off = np.asarray(offsets, dtype=np.int64)
    seg = np.zeros(len(pts))
    if len(pts) > 1:
        seg[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    seg[off[:-1][off[:-1] < len(pts)]] = 0.0  # no segment across a polyline's start
    cum = np.cumsum(seg)
    # (an empty polyline, e.g. a branch the ground cut away, may start at len(pts): clip its index)
    start = np.repeat(cum[np.minimum(off[:-1], len(pts) - 1)] if len(pts) else np.zeros(0), np.diff(off))
    x = cum - start
    lengths = np.zeros(len(off) - 1)
    nonempty = np.diff(off) > 0
    lengths[nonempty] = x[off[1:][nonempty] - 1]
    return x, lengths
