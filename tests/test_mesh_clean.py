"""Sliver clean-up keeps the ice closed and drops faces of next to no area."""

from __future__ import annotations

import numpy as np
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
