"""The storm figures on small synthetic inputs: boxes, slabs of ice, hand-made trajectories."""

import dataclasses
import math

import numpy as np
import pytest
import trimesh

from icefarm.bench.storm_figures import (
    StormFigures,
    glaze_coverage,
    ice_along_normals,
    nearest_root_distance,
    rain_reached_points,
    storm_figures,
)
from icefarm.stages.trajectories import TrajectoryResult

DOWN = (0.0, -1.0, 0.0)


def box(lo, hi):
    return trimesh.creation.box(bounds=[lo, hi])


@pytest.fixture(scope="module")
def unit_box():
    return box([0, 0, 0], [1, 1, 1])


def test_rain_reaches_the_whole_top_of_a_box(unit_box):
    points, normals = rain_reached_points(unit_box, DOWN, 2000, np.random.default_rng(0))
    assert len(points) == 2000  # nothing shades the top
    np.testing.assert_allclose(points[:, 1], 1.0)
    np.testing.assert_allclose(normals, np.broadcast_to([0, 1, 0], normals.shape))
    # By area: as many points on each half of the top.
    assert abs(np.mean(points[:, 0] < 0.5) - 0.5) < 0.05
    # Gravity along +x: the rain falls on the face looking against it, x = 0.
    points, normals = rain_reached_points(unit_box, (1.0, 0.0, 0.0), 100, np.random.default_rng(0))
    np.testing.assert_allclose(points[:, 0], 0.0)


def test_an_overhang_shades_what_lies_under_it():
    lower = box([0, 0, 0], [1, 0.1, 1])
    upper = box([0, 0.5, 0], [1, 0.6, 0.5])  # covers the half z < 0.5 of the lower slab
    points, _ = rain_reached_points(trimesh.util.concatenate([lower, upper]), DOWN, 4000, np.random.default_rng(1))
    on_lower = np.isclose(points[:, 1], 0.1)
    assert on_lower.any() and (points[on_lower, 2] > 0.5).all()
    assert np.isclose(points[~on_lower, 1], 0.6).all()
    # A third of the upward area (0.5 of 1.5 m^2) is shaded: about 2667 of 4000 points remain.
    assert abs(len(points) - 4000 * 2 / 3) < 150


def test_steep_faces_are_left_out():
    # A plank tilted 60 degrees from horizontal (its face's up component 0.5) and one tilted 80 (0.17).
    for angle, kept in ((60.0, True), (80.0, False)):
        mesh = box([-0.5, -0.01, -0.5], [0.5, 0.01, 0.5])
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.deg2rad(angle), [0, 0, 1]))
        _, normals = rain_reached_points(mesh, DOWN, 400, np.random.default_rng(2))
        assert np.isclose(normals[:, 1], np.cos(np.deg2rad(angle))).any() == kept
        assert (normals[:, 1] > 0.3).all()


@pytest.mark.parametrize("bottom", [0.99, 1.0])
def test_a_slab_of_ice_on_the_top_is_measured(unit_box, bottom):
    # bottom 0.99: a coat whose inner side lies inside the object; 1.0: ice resting on the top.
    ice = box([0, bottom, 0], [1, 1.005, 1])
    points, normals = rain_reached_points(unit_box, DOWN, 500, np.random.default_rng(3))
    thickness = ice_along_normals(ice, points, normals)
    np.testing.assert_allclose(thickness, 0.005, atol=2e-5)
    share, p50 = glaze_coverage(thickness)
    assert share == 1.0 and p50 == pytest.approx(0.005, abs=2e-5)


def test_no_ice_where_the_slab_does_not_reach(unit_box):
    ice = box([0, 0.99, 0], [0.5, 1.005, 1])  # half the top
    points = np.array([[0.25, 1.0, 0.5], [0.75, 1.0, 0.5], [1.0, 0.5, 0.5]])
    normals = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0]])
    thickness = ice_along_normals(ice, points, normals)
    np.testing.assert_allclose(thickness, [0.005, 0.0, 0.0], atol=2e-5)
    # Ice farther above than reach is not on the surface.
    high = box([0, 1.2, 0], [1, 1.3, 1])
    assert ice_along_normals(high, points[:1], normals[:1], reach=0.1)[0] == 0.0
    assert ice_along_normals(high, points[:1], normals[:1], reach=0.3)[0] == pytest.approx(0.1, abs=1e-5)
    assert (ice_along_normals(None, points, normals) == 0).all()


def test_glaze_coverage_counts_bare_points_in_the_median():
    share, p50 = glaze_coverage([0.0, 0.0, 0.0001, 0.003, 0.004])
    assert share == pytest.approx(0.4)
    assert p50 == pytest.approx(0.0001)
    assert all(math.isnan(v) for v in glaze_coverage([]))


def test_nearest_root_distance():
    roots = np.c_[np.arange(10) * 0.025, np.ones(10), np.zeros(10)]
    assert nearest_root_distance(roots) == pytest.approx(0.025)
    assert math.isnan(nearest_root_distance(roots[:1]))
    # A far outlier does not move the median.
    assert nearest_root_distance(np.r_[roots, [[5.0, 1.0, 0.0]]]) == pytest.approx(0.025)


def trajectories(roots, lengths):
    """Straight trunks hanging from ``roots``, three points each, and one side branch on the first."""
    points, offsets = [], [0]
    for root, length in zip(roots, lengths):
        points += [root - [0, f * length, 0] for f in (0.0, 0.5, 1.0)]
        offsets.append(len(points))
    points += [roots[0] - [0, 0.5 * lengths[0], 0], roots[0] - [0.01, 0.5 * lengths[0] + 0.02, 0]]
    offsets.append(len(points))
    k = len(roots)
    return TrajectoryResult(np.array(points, dtype=np.float64), np.array(offsets),
                            np.r_[np.arange(k), 0], np.r_[np.full(k, -1), 0])


def test_storm_figures_of_a_glazed_box_with_icicles(unit_box):
    roots = np.c_[np.arange(5) * 0.025 + 0.1, np.zeros(5), np.full(5, 0.5)]
    traj = trajectories(roots, [0.04, 0.05, 0.06, 0.07, 0.08])
    ice = box([0, 0.99, 0], [1, 1.005, 1])
    figures = storm_figures(unit_box, ice, traj, DOWN, np.random.default_rng(4), count=800)
    assert isinstance(figures, StormFigures)
    assert figures.icicles == 5  # the side branch is no icicle
    assert figures.median_trunk_m == pytest.approx(0.06)
    assert figures.nearest_root_m == pytest.approx(0.025)
    assert figures.glaze_coverage == 1.0
    assert figures.glaze_p50_m == pytest.approx(0.005, abs=2e-5)
    assert figures.rain_points == 800
    with pytest.raises(dataclasses.FrozenInstanceError):
        figures.icicles = 3  # the record is frozen


def test_storm_figures_without_ice_or_icicles(unit_box):
    empty = TrajectoryResult(np.zeros((0, 3)), np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                             np.zeros(0, dtype=np.int64))
    figures = storm_figures(unit_box, None, empty, DOWN, np.random.default_rng(5), count=100)
    assert figures.icicles == 0 and math.isnan(figures.median_trunk_m) and math.isnan(figures.nearest_root_m)
    assert figures.glaze_coverage == 0.0 and figures.glaze_p50_m == 0.0
