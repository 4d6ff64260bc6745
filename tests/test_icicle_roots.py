"""An icicle's root hangs from the object: on a rim it moves in under it instead of standing
in front of the face above as a glass dome."""

from __future__ import annotations

import numpy as np

from icefarm import params
from icefarm.stages.surface.icicles import ROOT_LEAN, hang_roots, root_shifts

G = np.array([0.0, -1.0, 0.0])


def test_roots_move_in_under_a_leaning_face_only_and_no_further_than_the_object_allows():
    normals = np.array([[0.0, -1.0, 0.0], [0.45, -0.89, 0.0], [1.0, 0.0, 0.0], [0.0, -0.99, 0.1]])
    thickness = np.array([0.05, 0.05, 0.004, np.inf])
    shift = root_shifts(normals, G, thickness)
    assert np.all(shift[0] == 0.0)  # under a face that looks down the ball's top is inside already
    assert np.allclose(shift[1], [-0.05, 0.0, 0.0])  # an eave's rim: horizontally in, under the eave
    assert np.allclose(shift[2], [-0.004, 0.0, 0.0])  # a thin wall: no further than it is thick
    assert np.all(shift[3] == 0.0)  # leaning less than ROOT_LEAN: stays
    assert np.hypot(*normals[3][[0, 2]]) < ROOT_LEAN
    assert np.all(root_shifts(normals[1:2], G, [np.inf]) == 0.0)  # an open mesh: no move


def test_a_trunk_moves_by_its_radius_at_the_root_and_not_below_it(surface_kit):
    traj = surface_kit.straight([[0.0, 0.0, 0.0]], [0.15])
    surface = params.resolve({"surface.noise": 0.0}).surface
    hung = hang_roots(traj, surface, np.array([[-0.1, 0.0, 0.0]]))
    offset = traj.points[:, 0] - hung.points[:, 0]
    depth = -traj.points[:, 1]  # the trunk hangs straight down from y = 0
    assert offset[0] > 0.005  # the root, a fat icicle's, moves in by its radius
    assert np.all(np.diff(offset[offset > 0]) < 0)  # less and less down the trunk
    assert np.all(offset[depth > 0.05] == 0.0)  # past its radius the trunk is where it was
    assert np.allclose(hung.points[:, 1:], traj.points[:, 1:])
    assert hang_roots(traj, surface, np.zeros((1, 3))) is traj  # nothing to move: the same axes
