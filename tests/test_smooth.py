"""The glaze coat's smoothing (`icefarm.stages.surface.smooth`): kinks smoothed, volume kept,
moves bounded, icicles and the coat's contact with the object left alone."""

import numpy as np
import trimesh

from icefarm.metaballs.field import BLOCK, Field
from icefarm.stages.surface import smooth

VOXEL = 0.004


def _kinked_sphere(radius=0.05, seed=0):
    """A sphere whose radius jumps by up to 0.6 mm from vertex to vertex (a coat's kinks)."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    rng = np.random.default_rng(seed)
    v = np.asarray(sphere.vertices) * (1.0 + rng.uniform(-0.6e-3, 0.6e-3, len(sphere.vertices)) / radius)[:, None]
    return v, np.asarray(sphere.faces)


def _roughness(v, f):
    """Mean angle (rad) between the normals of faces that share an edge."""
    mesh = trimesh.Trimesh(v, f, process=False)
    return float(mesh.face_adjacency_angles.mean())


def test_smoothing_removes_kinks_and_keeps_the_volume():
    v, f = _kinked_sphere()
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.04)  # the object, 1 cm under the coat
    out = smooth.smooth_glaze(v, f, VOXEL, smooth.coat_vertices(v, f, VOXEL, [], inner), 10)
    assert _roughness(out, f) < 0.5 * _roughness(v, f)
    before = trimesh.Trimesh(v, f, process=False).volume
    assert abs(trimesh.Trimesh(out, f, process=False).volume - before) < 0.01 * before
    moved = np.linalg.norm(out - v, axis=1)
    assert moved.max() <= smooth.MAX_MOVE * VOXEL * (1 + 1e-9)
    assert (moved > 0).mean() > 0.99


def test_nothing_moves_close_over_the_object_or_when_off():
    v, f = _kinked_sphere()
    skin = trimesh.creation.icosphere(subdivisions=4, radius=0.0495)  # the coat lies 0.5 mm over it
    assert np.array_equal(smooth.smooth_glaze(v, f, VOXEL, smooth.coat_vertices(v, f, VOXEL, [], skin), 10), v)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    assert np.array_equal(smooth.smooth_glaze(v, f, VOXEL, smooth.coat_vertices(v, f, VOXEL, [], inner), 0), v)


def test_icicle_vertices_and_their_neighbours_stay():
    v, f = _kinked_sphere()
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    # an icicle field above its level over the sphere's top (z > 3 cm): one block of samples
    origin = np.array([-0.032, -0.032, 0.03])
    values = np.zeros((1, BLOCK, BLOCK, BLOCK), np.float32)
    values[:] = 2.0
    icicle = Field(origin, VOXEL, 1.0, np.zeros((1, 3), dtype=np.int64), values)
    lattice = np.rint((v - origin) / VOXEL).astype(np.int64)
    icy = ((lattice >= 0) & (lattice < BLOCK)).all(axis=1)
    assert 0 < icy.sum() < len(v)
    anchored = np.zeros(len(v), dtype=bool)
    anchored[f[icy[f].any(axis=1)]] = True
    out = smooth.smooth_glaze(v, f, VOXEL, smooth.coat_vertices(v, f, VOXEL, [icicle], inner), 10)
    assert np.array_equal(out[anchored], v[anchored])
    assert (np.linalg.norm(out[~anchored] - v[~anchored], axis=1) > 0).mean() > 0.99


def test_a_shell_close_over_the_object_stays_beside_one_that_moves():
    # The coat's hidden inner face is a second shell, under the object's surface: its
    # vertices come last and are in none of the faces that move.
    v, f = _kinked_sphere()
    inner_v, inner_f = _kinked_sphere(radius=0.038, seed=1)
    verts, faces = np.concatenate([v, inner_v]), np.concatenate([f, inner_f + len(v)])
    surface = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    out = smooth.smooth_glaze(verts, faces, VOXEL, smooth.coat_vertices(verts, faces, VOXEL, [], surface), 10)
    assert np.array_equal(out[len(v):], inner_v)
    assert np.isfinite(out).all()
    assert (np.linalg.norm(out[:len(v)] - v, axis=1) > 0).mean() > 0.99


def test_the_same_as_trimesh_taubin_over_the_whole_mesh(monkeypatch):
    # Filtering only the free vertices and their neighbours is trimesh's filter over the
    # whole mesh with every other vertex pinned (moves uncapped for the comparison).
    v, f = _kinked_sphere()
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    origin = np.array([-0.032, -0.032, 0.03])
    values = np.full((1, BLOCK, BLOCK, BLOCK), 2.0, np.float32)
    icicle = Field(origin, VOXEL, 1.0, np.zeros((1, 3), dtype=np.int64), values)
    lattice = np.rint((v - origin) / VOXEL).astype(np.int64)
    icy = ((lattice >= 0) & (lattice < BLOCK)).all(axis=1)
    pinned = np.zeros(len(v), dtype=bool)
    pinned[f[icy[f].any(axis=1)]] = True
    monkeypatch.setattr(smooth, "MAX_MOVE", 1e9)
    out = smooth.smooth_glaze(v, f, VOXEL, smooth.coat_vertices(v, f, VOXEL, [icicle], inner), 10)
    mesh = trimesh.Trimesh(v, f, process=False)
    operator = trimesh.smoothing.laplacian_calculation(mesh, pinned_vertices=np.flatnonzero(pinned))
    lamb, mu = smooth.TAUBIN
    ref = trimesh.smoothing.filter_taubin(mesh, lamb=lamb, nu=-mu, iterations=20, laplacian_operator=operator).vertices
    assert np.allclose(out, ref, rtol=0, atol=1e-12)
    assert np.abs(out - v).max() > 1e-5
