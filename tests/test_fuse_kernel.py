"""The local union's compiled bookkeeping against the NumPy it replaced."""

import numpy as np

from icefarm.geometry import face_count
from icefarm.metaballs.fuse_kernel import INNER, OUTER, compacted, kept_outside, vertex_sides, welded


def _mesh(seed, n=50, m=200):
    rng = np.random.default_rng(seed)
    faces = np.stack([rng.choice(n, 3, replace=False) for _ in range(m)]).astype(np.int64)
    return rng, faces, n


def _used(faces, n):
    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    return used


def test_vertex_sides_tell_the_vertices_of_inner_faces_other_faces_and_the_seam():
    for seed in range(5):
        rng, faces, n = _mesh(seed, n=300)
        inner = rng.random(len(faces)) < 0.4
        use = vertex_sides(faces, inner, n)
        assert np.array_equal((use & INNER) != 0, _used(faces[inner], n))
        assert np.array_equal((use & OUTER) != 0, _used(faces[~inner], n))
        assert np.array_equal(use == INNER | OUTER, _used(faces[inner], n) & _used(faces[~inner], n))
        assert not use[~_used(faces, n)].any()


def test_kept_outside_keeps_the_outer_faces_wholly_out_of_the_other_solid_in_order():
    for seed in range(5):
        rng, faces, n = _mesh(seed)
        inner = rng.random(len(faces)) < 0.3
        covered = (rng.random(n) < 0.05).astype(np.uint8)
        kept, split = kept_outside(faces, inner, covered)
        out = faces[~inner]
        count = face_count(covered.astype(bool), out)
        assert np.array_equal(kept, out[count == 0])
        assert split == bool(((count > 0) & (count < 3)).any())
    # a face of the region is never asked: wholly covered inner faces stay out of both answers
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    kept, split = kept_outside(faces, np.array([True, False]), np.array([1, 1, 0, 0, 0], dtype=np.uint8))
    assert kept.tolist() == [[2, 3, 4]] and not split


def test_welded_shifts_renumbers_and_flags_a_face_that_lost_a_corner():
    rng, a, n = _mesh(1, n=40, m=30)
    b, c = a[:10].copy(), a[5:25].copy()
    offsets = np.array([0, 40, 80])
    index = np.arange(120)
    index[40:80] = np.arange(40)  # b's vertices weld onto a's
    faces, degenerate = welded((a, b, c), offsets, index)
    assert np.array_equal(faces, index[np.concatenate([a, b + 40, c + 80])]) and not degenerate
    index[1] = 0
    _, degenerate = welded((a, b, c), offsets, index)
    assert degenerate == bool((np.isin(a, [0, 1]).sum(axis=1) == 2).any())


def test_compacted_renumbers_faces_over_the_vertices_they_use():
    rng, faces, n = _mesh(2, n=500, m=60)
    out, used = compacted(faces, n)
    mask = _used(faces, n)
    assert np.array_equal(used, np.flatnonzero(mask))
    assert np.array_equal(out, (np.cumsum(mask) - 1)[faces])
    points = rng.random((n, 3))
    assert np.array_equal(points[used][out], points[faces])
