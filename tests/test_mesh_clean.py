"""Sliver clean-up keeps the ice closed and drops faces of next to no area."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from icefarm.metaballs.clean import collapse_slivers


def _split_edge_near_its_end(mesh: trimesh.Trimesh, offset: float):
    """The mesh with one edge split a hair from its first end: two sliver faces."""
    faces = mesh.faces.tolist()
    a, b = mesh.edges_unique[0]
    d = len(mesh.vertices)
    vertices = np.vstack([mesh.vertices, mesh.vertices[a] + offset * (mesh.vertices[b] - mesh.vertices[a])])
    out = []
    for f in faces:
        if a in f and b in f:
            i = f.index(a)
            rolled = f[i:] + f[:i]  # a first
            if rolled[1] == b:      # (a, b, c) -> (a, d, c), (d, b, c)
                out += [[a, d, rolled[2]], [d, b, rolled[2]]]
            else:                   # (a, c, b) -> (a, c, d), (d, c, b)
                out += [[a, rolled[1], d], [d, rolled[1], b]]
        else:
            out.append(f)
    return vertices, np.array(out)


def test_a_sliver_is_collapsed_and_the_mesh_stays_closed():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    vertices, faces = _split_edge_near_its_end(sphere, 1e-7)
    before = trimesh.Trimesh(vertices, faces, process=False)
    assert before.is_watertight and before.area_faces.min() < 1e-10
    v, f = collapse_slivers(vertices, faces, 1e-6)
    after = trimesh.Trimesh(v, f, process=False)
    assert after.is_watertight and after.is_winding_consistent
    assert len(f) == len(sphere.faces) and after.area_faces.min() > 1e-6
    assert after.volume == trimesh.Trimesh(sphere.vertices, sphere.faces).volume


def test_nothing_to_collapse_returns_the_mesh_as_it_was():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    v, f = collapse_slivers(sphere.vertices, sphere.faces, 1e-6)
    assert np.array_equal(f, sphere.faces) and np.array_equal(v, sphere.vertices)


def test_a_needle_is_flipped_away_and_the_mesh_stays_closed():
    from icefarm.metaballs.clean import _heights, flip_needles

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    vertices = sphere.vertices.copy()
    u, v, w = sphere.faces[0]
    # Pull w onto the middle of u-v: a needle with no short edge to collapse.
    vertices[w] = 0.5 * (vertices[u] + vertices[v]) + 1e-10 * sphere.face_normals[0]
    assert _heights(vertices, sphere.faces).min() < 1e-9
    faces = flip_needles(vertices, sphere.faces, 1e-6)
    after = trimesh.Trimesh(vertices, faces, process=False)
    assert after.is_watertight and after.is_winding_consistent
    assert _heights(vertices, faces).min() > 1e-6


@pytest.mark.parametrize("seed", [0, 4, 5])  # unions where the clean-up collapses a vertex
def test_slivers_are_found_where_the_union_cut_and_cleaned_as_everywhere(seed):
    from icefarm import metaballs as M
    from icefarm.metaballs.clean import _flat, clean_slivers, flip_needles, sliver_candidates

    def sphere(centre, radius, voxel):
        balls = M.Balls(np.array([centre], float), np.array([radius]), np.array([M.LEVEL * np.e]))
        return M.sample_field(balls, voxel)

    rng = np.random.default_rng(seed)
    fields = [sphere([0, 0, 0], 0.02, 0.001), sphere(rng.uniform(0.01, 0.02, 3), 0.015, 0.0037)]
    v, f = M.fuse_fields(*fields)
    tol = 1e-3 * 0.001
    tri = v[f]
    thin = (np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2) < tol).any(axis=1) | _flat(v, f, tol)
    assert thin.any()  # the union cut some
    near = sliver_candidates(v, fields, tol)
    assert near[f[thin]].any(axis=1).all()
    assert near.mean() < 0.1  # a few vertices, not the mesh
    whole_v, whole_f = collapse_slivers(v, f, tol)
    whole_f = flip_needles(whole_v, whole_f, tol)
    near_v, near_f, kept = clean_slivers(v, f, tol, near=near)
    assert np.array_equal(near_v, whole_v) and np.array_equal(near_f, whole_f)
    # kept says which input vertex each one is: per-vertex values index with it
    assert len(kept) == len(near_v) < len(v) and np.array_equal(v[kept], near_v)
