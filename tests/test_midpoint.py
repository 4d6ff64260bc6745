"""Midpoint refinement (`icefarm.midpoint`) against pymeshlab's, and what it keeps."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from icefarm.generators import generate
from icefarm.meshlab import current, meshset
from icefarm.midpoint import split_long_edges
from icefarm.stages.storm import refine


def _pymeshlab(mesh, max_edge):
    import pymeshlab

    ms = meshset(mesh)
    ms.meshing_surface_subdivision_midpoint(iterations=20, threshold=pymeshlab.PureValue(max_edge))
    return current(ms)


@pytest.mark.parametrize("name, edge", [("table", 0.05), ("sign", 0.04), ("car", 0.1)])
def test_the_surface_of_pymeshlabs_midpoint_refinement(name, edge):
    mesh = generate(name)
    theirs = _pymeshlab(mesh, edge)
    vertices, faces = split_long_edges(mesh.vertices, mesh.faces, edge)
    ours = trimesh.Trimesh(vertices, faces, process=False)
    assert ours.is_watertight and ours.is_winding_consistent  # conforming: no T-junctions
    assert ours.edges_unique_length.max() <= edge < mesh.edges_unique_length.max()
    assert ours.area == pytest.approx(mesh.area, rel=1e-12)
    assert ours.volume == pytest.approx(mesh.volume, rel=1e-12)
    assert np.array_equal(vertices[:len(mesh.vertices)], mesh.vertices)
    # as many faces, most at the same places: pymeshlab keeps float32 positions, so where the
    # two diagonals of a split quad tie it may take the other one (then splits that differently)
    assert abs(len(faces) - len(theirs.faces)) <= 0.02 * len(theirs.faces)
    distance = cKDTree(vertices).query(theirs.vertices)[0]
    assert (distance < 1e-6 * mesh.scale).mean() > 0.8


def test_new_vertices_lie_on_the_original_faces_and_windings_are_kept():
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    vertices, faces = split_long_edges(mesh.vertices, mesh.faces, 0.2)
    _, distance, _ = trimesh.proximity.closest_point(mesh, vertices)
    assert distance.max() < 1e-12
    ours = trimesh.Trimesh(vertices, faces, process=False)
    assert ours.is_watertight and ours.volume > 0  # outward still
    assert len(faces) == 16 * len(mesh.faces)  # equilateral enough: two rounds of 1 to 4


def test_short_edges_stay_and_bad_lengths_are_refused():
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    vertices, faces = split_long_edges(mesh.vertices, mesh.faces, 2.0)
    assert np.array_equal(faces, mesh.faces) and len(vertices) == len(mesh.vertices)
    with pytest.raises(ValueError, match="max_edge"):
        split_long_edges(mesh.vertices, mesh.faces, 0.0)


def test_refine_welds_a_seam_first():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    split = trimesh.Trimesh(box.vertices[box.faces].reshape(-1, 3), np.arange(36).reshape(-1, 3), process=False)
    out = refine(split, 0.3)
    assert out.is_watertight and out.edges_unique_length.max() <= 0.3


def test_refine_refuses_edges_of_three_faces_as_pymeshlab_did():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    fin = trimesh.Trimesh(np.r_[box.vertices, [[0.5, 0.5, 2.0]]], np.r_[box.faces, [[4, 5, 8]]], process=False)
    shared = np.bincount(fin.edges_unique_inverse).max()
    assert shared == 3
    with pytest.raises(ValueError, match="at most two faces"):
        refine(fin, 0.3)
