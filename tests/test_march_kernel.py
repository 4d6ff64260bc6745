"""The compiled marching cubes (`icefarm.metaballs.march_kernel`) and its case tables."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from icefarm.metaballs import CUTOFF, LEVEL, MARCH_POWER, march_blocks
from icefarm.metaballs.cube_cases import EDGES, cube_cases

_FACES = ((0, 2, 6, 4), (1, 3, 7, 5), (0, 1, 5, 4), (2, 3, 7, 6), (0, 1, 3, 2), (4, 5, 7, 6))


def test_each_case_cuts_its_crossed_edges_and_no_triangle_lies_in_a_face():
    cases = cube_cases()
    for case in range(256):
        inside = [case >> c & 1 for c in range(8)]
        crossed = {e for e, (a, b) in enumerate(EDGES) if inside[a] != inside[b]}
        tris = cases.triangles[case, :cases.n_triangles[case]]
        assert set(tris.ravel().tolist()) == crossed
        for tri in tris:
            corners = {int(c) for e in tri for c in EDGES[e]}
            assert not any(corners <= set(face) for face in _FACES), (case, tri)


@pytest.mark.parametrize("seed", range(4))
def test_noise_marches_to_a_closed_outward_two_manifold(seed):
    # Noise makes every case, the ambiguous ones included, and seams between blocks.
    rng = np.random.default_rng(seed)
    blocks = np.array([[1, 1, 1], [1, 1, 2], [1, 2, 1], [2, 1, 1], [2, 2, 2]])
    values = rng.uniform(0.0, 2.0 * LEVEL, (len(blocks), 16, 16, 16)).astype(np.float32)
    lattice, faces = march_blocks(values, blocks, LEVEL)
    mesh = trimesh.Trimesh(lattice, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    import manifold3d

    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=lattice, tri_verts=faces.astype(np.uint64)))
    assert solid.status() == manifold3d.Error.NoError
    # Every vertex lies on a lattice edge, between samples on either side of the level.
    frac = lattice - np.floor(lattice)
    assert ((frac > 0).sum(axis=1) <= 1).all()


def test_vertices_and_area_match_scikit_image():
    from skimage.measure import marching_cubes

    x = np.arange(16, dtype=np.float64)
    g = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1)
    field = sum(w * np.exp(-np.sum((g - c) ** 2, axis=-1) / 9.0)
                for c, w in (((6, 7, 8), 1.0), ((9, 8, 8), 0.8), ((7, 9, 6), 0.6)))
    level = 0.5
    assert field[[0, -1]].max() < level and field[:, [0, -1]].max() < level and field[:, :, [0, -1]].max() < level
    lattice, faces = march_blocks(field.astype(np.float32)[None], np.array([[1, 1, 1]]), level)
    lattice -= 16
    # scikit-image on the same domain: the field padded with zeros, clamped, to the power,
    # and pushed a thousandth off the level
    padded = np.pad(field.astype(np.float32), (0, 1)).astype(np.float64)
    dense, t_level = np.maximum(padded, CUTOFF * level) ** MARCH_POWER, level**MARCH_POWER
    near = np.abs(dense - t_level) < 1e-3 * t_level
    dense[near] = np.where(padded[near] > level, 1.001, 0.999) * t_level
    v, f, _, _ = marching_cubes(dense, level=t_level, gradient_direction="ascent")
    on_edge = ((v - np.floor(v)) > 0).sum(axis=1) <= 1  # scikit-image adds a few vertices inside cells
    assert len(lattice) == on_edge.sum()
    assert cKDTree(v).query(lattice)[0].max() < 1e-4
    ours = trimesh.Trimesh(lattice, faces, process=False)
    theirs = trimesh.Trimesh(v, f, process=False)
    assert ours.is_watertight and ours.area == pytest.approx(theirs.area, rel=2e-3)
    assert ours.volume == pytest.approx(theirs.volume, rel=2e-3)


def test_blocks_too_far_apart_to_number_their_edges_are_refused_not_wrapped():
    values = np.full((2, 16, 16, 16), 2.0 * LEVEL, dtype=np.float32)
    far = np.array([[1, 1, 1], [2**19, 2**19, 2**19]])
    with pytest.raises(ValueError, match="span too many samples"):
        march_blocks(values, far, LEVEL)
    lattice, faces = march_blocks(values[:1], far[:1], LEVEL)  # one of them alone: a closed box
    assert trimesh.Trimesh(lattice, faces, process=False).is_watertight
