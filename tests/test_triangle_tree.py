"""The compiled triangle tree finds the hits Embree finds."""

import numpy as np
import trimesh

from icefarm.spatial import ray_caster
from icefarm.triangle_tree import triangle_tree


def _rays(mesh, n, seed):
    rng = np.random.default_rng(seed)
    origins = mesh.bounds[0] - 0.2 * mesh.extents + rng.random((n, 3)) * 1.4 * mesh.extents
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=1)[:, None]


def test_hits_faces_and_distances_agree_with_embree(shared_mesh):
    bunny = trimesh.load(shared_mesh("stanford-bunny.obj"), force="mesh")  # open at the bottom
    bunny.apply_scale(0.3 / bunny.extents.max())
    for mesh in (bunny, trimesh.creation.icosphere(subdivisions=3, radius=0.5), trimesh.creation.box((1, 2, 0.1))):
        origins, directions = _rays(mesh, 4000, 1)
        embree = ray_caster(mesh)(origins, directions)
        ours = triangle_tree(mesh.vertices, mesh.faces).cast(origins, directions)
        hit = np.isfinite(embree[0])
        assert 0.2 < hit.mean() < 1.0  # some rays miss, most from inside hit
        assert np.array_equal(np.isfinite(ours[0]), hit)
        assert np.array_equal(ours[1] >= 0, hit)
        assert np.abs(ours[0][hit] - embree[0][hit]).max() < 1e-6 * mesh.scale
        # a ray through an edge may report either face: the distance agrees
        assert (ours[1] == embree[1]).mean() > 0.99


def test_axis_aligned_rays_and_misses():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    tree = triangle_tree(box.vertices, box.faces)
    origins = np.array([[0.1, 0.2, -3.0], [0.1, 0.2, 0.0], [3.0, 3.0, 0.0], [0.0, 0.0, 0.0]])
    directions = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    dist, face = tree.cast(origins, directions)
    assert np.allclose(dist, [2.5, 0.6, np.inf, 0.5])
    assert (face[[0, 1, 3]] >= 0).all() and face[2] == -1
    assert np.allclose(box.face_normals[face[[0, 1, 3]]], [[0, 0, -1], [-1, 0, 0], [0, 1, 0]])


def test_an_empty_mesh_is_never_hit():
    tree = triangle_tree(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    dist, face = tree.cast(np.zeros((2, 3)), np.array([[0, 0, 1.0], [1.0, 0, 0]]))
    assert np.isinf(dist).all() and (face == -1).all()
