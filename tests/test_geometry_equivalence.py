"""Hand-written geometry kept for speed gives what trimesh, or a plain loop, gives."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from icefarm import geometry, spatial
from icefarm.geometry import arc_lengths, face_cross, ragged_arange, sample_faces, signed_volume
from icefarm.scene.geometry import smooth_normals
from icefarm.spatial import closest_point


@pytest.fixture
def lumpy(sphere) -> trimesh.Trimesh:
    """The conftest sphere with its vertices jittered, so faces differ in size and angle."""
    jitter = np.random.default_rng(0).normal(scale=0.005, size=sphere.vertices.shape)
    return trimesh.Trimesh(sphere.vertices + jitter, sphere.faces, process=False)


def test_face_cross_is_trimesh_cross(lumpy):
    np.testing.assert_allclose(face_cross(lumpy.vertices, lumpy.faces), trimesh.triangles.cross(lumpy.triangles),
                               rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("share", [0.0, 0.05, 0.5, 1.0])
def test_face_any_all_count_are_numpys_reductions(share):
    rng = np.random.default_rng(1)
    mask = rng.random(500) < share
    faces = rng.integers(0, 500, (2000, 3))
    edges = faces[:, :2]
    assert np.array_equal(geometry.face_any(mask, faces), mask[faces].any(axis=1))
    assert np.array_equal(geometry.face_any(mask, edges), mask[edges].any(axis=1))
    assert np.array_equal(geometry.face_all(mask, faces), mask[faces].all(axis=1))
    assert np.array_equal(geometry.face_count(mask, faces), mask[faces].sum(axis=1))
    assert not np.shares_memory(geometry.face_any(mask, faces), mask)


def test_within_box_is_numpys_reduction_over_rows():
    points = np.random.default_rng(3).normal(size=(5000, 3))
    points[:10] = [[0.5, -0.25, 1.0]] * 10  # on the box's faces: inside
    lo, hi = np.array([-0.5, -0.25, -1.0]), np.array([0.5, 0.75, 1.0])
    box = geometry.within_box(points, lo, hi)
    assert np.array_equal(box, ((points >= lo) & (points <= hi)).all(axis=1)) and box[:10].all()
    assert 0 < box.mean() < 1


def test_signed_volume_is_trimesh_volume(lumpy):
    assert signed_volume(lumpy.vertices, lumpy.faces) == pytest.approx(lumpy.volume, rel=1e-12)
    inverted = lumpy.copy()
    inverted.invert()
    inverted.apply_translation([1.0, 0.0, 0.0])
    both = trimesh.util.concatenate([lumpy, inverted])
    labels = np.repeat([0, 1], len(lumpy.faces))
    np.testing.assert_allclose(signed_volume(both.vertices, both.faces, labels=labels),
                               [lumpy.volume, inverted.volume], rtol=1e-12)
    assert inverted.volume < 0


def test_smooth_normals_are_trimesh_vertex_normals(lumpy):
    # an unused vertex gets a zero normal from both
    mesh = trimesh.Trimesh(np.vstack([lumpy.vertices, [[5.0, 0.0, 0.0]]]), lumpy.faces, process=False)
    ours = smooth_normals(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(ours, mesh.vertex_normals, atol=1e-12)
    assert not ours[-1].any()


def test_sample_faces_picks_trimesh_faces_and_spreads_like_it(lumpy):
    subset = np.flatnonzero(lumpy.triangles_center[:, 1] > 0.05)  # sorted, as sample_surface sees it
    weight = np.zeros(len(lumpy.faces))
    weight[subset] = lumpy.area_faces[subset]
    n = 20000
    points, face, bary = sample_faces(lumpy, subset, n, np.random.default_rng(7))
    _, want_face, want_bary = trimesh.sample.sample_surface(
        lumpy, n, face_weight=weight, return_barycentric=True, seed=np.random.default_rng(7))
    # the same draws pick the same faces; the points in them are drawn another way
    np.testing.assert_array_equal(face, want_face)
    np.testing.assert_allclose(points, trimesh.triangles.barycentric_to_points(lumpy.triangles[face], bary),
                               atol=1e-15)
    assert bary.min() >= 0 and np.allclose(bary.sum(axis=1), 1)
    # uniform in a triangle: mean 1/3, second moment 1/6 per coordinate, as trimesh's
    for got in (bary, want_bary):
        np.testing.assert_allclose(got.mean(axis=0), 1 / 3, atol=0.01)
        np.testing.assert_allclose((got**2).mean(axis=0), 1 / 6, atol=0.01)


def _brute_distance(mesh, points):
    """Distance from each point to the nearest of all triangles, one point at a time."""
    return np.array([np.linalg.norm(trimesh.triangles.closest_point(
        mesh.triangles, np.repeat(p[None], len(mesh.faces), 0)) - p, axis=1).min() for p in points])


@pytest.mark.parametrize("fallback", [False, True])
def test_closest_point_is_exact_and_never_farther_than_trimeshs(lumpy, monkeypatch, fallback):
    if fallback:  # the R-tree path, taken when the candidate ball grows too large
        monkeypatch.setattr(spatial, "CLOSEST_CANDIDATES_MAX", 1)
    # One huge triangle among small ones: the ball must still find every nearest face.
    big = trimesh.Trimesh([[-3, -3, 2], [3, -3, 2], [0, 3, 2]], [[0, 1, 2]])
    mesh = trimesh.util.concatenate([lumpy, big])
    rng = np.random.default_rng(2)
    points = np.vstack([mesh.vertices[rng.choice(len(lumpy.vertices), 30)] + rng.normal(0, 0.02, (30, 3)),
                        rng.uniform(-2, 2, (10, 3))])
    closest, distance, faces = closest_point(mesh, points)
    np.testing.assert_allclose(distance, np.linalg.norm(closest - points, axis=1), atol=1e-12)
    np.testing.assert_allclose(distance, _brute_distance(mesh, points), atol=1e-9 if not fallback else 1e-3)
    theirs = trimesh.proximity.closest_point(mesh, points)[1]
    assert np.all(distance <= theirs + 1e-12)
    on_face = trimesh.triangles.closest_point(mesh.triangles[faces], points)
    np.testing.assert_allclose(on_face, closest, atol=1e-9)


def test_flat_faces_test_agrees_with_the_heights():
    from icefarm.metaballs.clean import _flat, _heights

    rng = np.random.default_rng(5)
    v = rng.random((2000, 3))
    f = rng.integers(0, 2000, (5000, 3))
    v[f[:40, 2]] = 0.5 * (v[f[:40, 0]] + v[f[:40, 1]]) + 1e-7  # needles: a corner on the opposite edge
    for height in (1e-6, 1e-3, 0.05):
        assert np.array_equal(_flat(v, f, height), _heights(v, f) < height)


def test_ragged_arange_counts_within_each_group():
    counts = np.array([3, 0, 1, 4, 0, 2])
    expected = np.concatenate([np.arange(c) for c in counts])
    np.testing.assert_array_equal(ragged_arange(counts), expected)
    assert ragged_arange(counts).dtype == np.int64
    np.testing.assert_array_equal(ragged_arange(counts, dtype=np.int32), expected)
    assert ragged_arange(counts, dtype=np.int32).dtype == np.int32
    assert ragged_arange(np.zeros(0, dtype=np.int64)).shape == (0,)


def test_arc_lengths_are_each_polylines_own():
    """Polylines of 4, 0, 1 and 3 points, then an empty one that starts past the last point."""
    rng = np.random.default_rng(2)
    points = rng.random((8, 3))
    offsets = np.array([0, 4, 4, 5, 8, 8])
    x, lengths = arc_lengths(points, offsets)
    for b in range(len(offsets) - 1):
        line = points[offsets[b]:offsets[b + 1]]
        steps = np.linalg.norm(np.diff(line, axis=0), axis=1)
        np.testing.assert_allclose(x[offsets[b]:offsets[b + 1]], np.r_[0.0, np.cumsum(steps)][:len(line)], atol=1e-12)
        assert lengths[b] == pytest.approx(steps.sum(), abs=1e-12)
    x, lengths = arc_lengths(np.zeros((0, 3)), [0, 0])
    assert x.shape == (0,) and lengths.tolist() == [0.0]


def test_nearest_is_scipys_nearest_neighbour():
    from scipy.spatial import cKDTree

    from icefarm.spatial import nearest, point_index

    rng = np.random.default_rng(3)
    points = rng.random((5000, 3))
    query = rng.random((20000, 3)) * 1.4 - 0.2  # some far outside the points
    d_ref, i_ref = cKDTree(points).query(query, k=1, distance_upper_bound=0.05)
    d, i = nearest(point_index(points), query, 0.05)
    found = np.isfinite(d_ref)
    assert 0 < found.sum() < len(query)
    np.testing.assert_array_equal(i >= 0, found)
    np.testing.assert_array_equal(i[found], i_ref[found])
    np.testing.assert_array_equal(d[found], d_ref[found])
    assert np.all(i[~found] == -1) and np.all(np.isinf(d[~found]))
    # no bound: every point finds one; nothing to look in, or nothing to look for: none
    assert (nearest(point_index(points), query)[1] >= 0).all()
    assert (nearest(point_index(np.zeros((0, 3))), query[:5])[1] == -1).all()
    assert nearest(point_index(points), np.zeros((0, 3)))[0].shape == (0,)


def test_near_caster_hits_what_the_whole_tree_hits():
    # Fine faces beside coarse ones (an icicle's lattice beside a glaze coat's), and few rays
    # for the mesh, so that the first round's tree holds a small part of it: rays that hit
    # close, hit past the first round, start outside the box, run along an axis or miss.
    rng = np.random.default_rng(3)
    fine = trimesh.creation.icosphere(subdivisions=5, radius=0.15)
    fine.vertices += rng.normal(scale=0.001, size=fine.vertices.shape)
    coarse = trimesh.creation.box(extents=(0.6, 0.6, 0.05))
    coarse.apply_translation([0.0, 0.0, -0.3])
    mesh = trimesh.util.concatenate([fine, coarse])
    n = 150
    origins = np.concatenate([fine.vertices[rng.integers(0, len(fine.vertices), n)] + rng.normal(0, 0.01, (n, 3)),
                              rng.uniform(-0.5, 0.5, (n, 3))])
    directions = rng.normal(size=(2 * n, 3))
    axis = np.arange(0, 2 * n, 7)
    directions[axis] = np.eye(3)[rng.integers(0, 3, len(axis))] * rng.choice([-1.0, 1.0], (len(axis), 1))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    want_d, want_f = spatial.ray_caster(mesh)(origins, directions)
    got_d, got_f = spatial.near_caster(mesh.vertices, mesh.faces, 0.02)(origins, directions)
    np.testing.assert_array_equal(got_f, want_f)
    np.testing.assert_array_equal(got_d, want_d)
    assert 0.2 < np.isfinite(want_d).mean() < 0.9  # hits and misses both tried
    assert (want_d[np.isfinite(want_d)] > 0.1).sum() > 20  # and hits past the first round


def test_every_caster_cut_at_far_hits_what_it_hits_unbounded_within_far():
    from icefarm.triangle_tree import triangle_tree

    rng = np.random.default_rng(5)
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=3, radius=0.15),
                                     trimesh.creation.box(extents=(0.6, 0.6, 0.05)).apply_translation([0, 0, -0.3])])
    origins = rng.uniform(-0.4, 0.4, (400, 3))
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for cast in (spatial.ray_caster(mesh), spatial.near_caster(mesh.vertices, mesh.faces, 0.02),
                 triangle_tree(mesh.vertices, mesh.faces).cast):
        whole_d, whole_f = cast(origins, directions)
        far = float(np.median(whole_d[np.isfinite(whole_d)]))
        d, f = cast(origins, directions, far=far)
        within = whole_d <= far
        assert 20 < within.sum() < np.isfinite(whole_d).sum()  # hits both sides of far
        np.testing.assert_array_equal(f[within], whole_f[within])
        np.testing.assert_array_equal(d[within], whole_d[within])
        assert np.isinf(d[~within]).all() and (f[~within] == -1).all()


def test_near_caster_misses_where_no_face_comes_near(sphere):
    cast = spatial.near_caster(sphere.vertices, sphere.faces, 0.01)
    # outside the box; through a corner of the box, past the sphere (no face near); a hit
    distance, face = cast(np.array([[1.0, 1.0, 1.0], [0.14, 0.14, -1.0], [0.0, 0.0, 0.0]]),
                          np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
    assert np.isinf(distance[:2]).all() and (face[:2] == -1).all()
    assert distance[2] == pytest.approx(0.15, abs=0.01) and face[2] >= 0
    distance, face = cast(np.array([[0.14, 0.14, -1.0]]), np.array([[0.0, 0.0, 1.0]]))  # alone: no face at all
    assert np.isinf(distance[0]) and face[0] == -1
    empty = spatial.near_caster(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0.01)
    assert np.isinf(empty(np.zeros((2, 3)), np.eye(3)[:2])[0]).all()


def test_the_field_filled_on_every_core_is_the_field_filled_on_one(monkeypatch):
    from icefarm.metaballs import Balls, sample_field

    rng = np.random.default_rng(4)
    n = 400
    balls = Balls(rng.uniform(-0.05, 0.05, (n, 3)), rng.uniform(0.002, 0.006, n), np.ones(n))
    several = sample_field(balls, 0.001)
    monkeypatch.setattr("icefarm.metaballs.field.os.cpu_count", lambda: 1)
    one = sample_field(balls, 0.001)
    assert len(several.blocks) > 20
    assert np.array_equal(several.blocks, one.blocks) and np.array_equal(several.values, one.values)


def test_stable_order_is_numpys_stable_argsort():
    from icefarm.geometry import stable_order

    rng = np.random.default_rng(7)
    # counted (keys from a small range, negative ones too), quicksorted, merge-sorted
    for keys in (rng.integers(0, 50, 10_000), rng.integers(-5, 5, 1_000), rng.integers(7, 7 + 4 * 3_000, 3_000),
                 rng.integers(0, 10**6, 5_000).astype(np.int32), rng.integers(0, 20_000, 4_000).astype(np.uint32),
                 np.array([2**61, 1, 2**61, 0]), np.zeros(0, dtype=np.int64), np.array([3, 1, 2, 1, 3])):
        np.testing.assert_array_equal(stable_order(keys), np.argsort(keys, kind="stable"))
