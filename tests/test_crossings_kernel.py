"""The slab radius's compiled crossings against the NumPy they replaced."""

import numpy as np
import trimesh

from icefarm.geometry import face_all, ragged_arange
from icefarm.stages.surface.measure import _crossings, _on_trunks, _trunk_starts


def _numpy_crossings(vert, sample, along, radial, n_vertices, faces, trunk, x, step):
    s, r, t = _on_trunks(vert, sample, along, radial, n_vertices, trunk, x)
    faces = faces[face_all(t >= 0, faces)]
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    up = (t[a] == t[b]) & (s[a] < s[b])
    a, b = a[up], b[up]
    first, points = _trunk_starts(trunk)
    start = first[t[a]]
    x0 = x[start]
    lo = np.maximum(np.floor((s[a] - x0) / step).astype(np.int64) + 1, 0)
    hi = np.minimum(np.floor((s[b] - x0) / step).astype(np.int64), points[t[a]] - 1)
    count = np.maximum(hi - lo + 1, 0)
    edge = np.repeat(np.arange(len(a)), count)
    j = lo[edge] + ragged_arange(count)
    sa, sb, ra, rb = s[a][edge], s[b][edge], r[a][edge], r[b][edge]
    w = (x0[edge] + j * step - sa) / (sb - sa)
    return start[edge] + j, ra + w * (rb - ra)


def test_crossings_are_the_numpy_ones_in_the_same_order():
    rng = np.random.default_rng(2)
    # two icicles (cones along -z), their axes sampled every 2 mm, and a stray box near none
    parts, axes, trunk = [], [], []
    for i, (cx, length) in enumerate(((0.0, 0.12), (0.05, 0.07))):
        cone = trimesh.creation.cone(radius=0.01, height=length, sections=24)
        cone = cone.subdivide().subdivide()
        cone.vertices[:, 2] *= -1
        cone.vertices += [cx, 0.0, length]
        cone.vertices += rng.normal(scale=2e-4, size=cone.vertices.shape)
        parts.append(cone)
        z = np.arange(length, 0.0, -0.002)
        axes.append(np.c_[np.full(len(z), cx), np.zeros(len(z)), z])
        trunk.append(np.full(len(z), i))
    box = trimesh.creation.box(extents=(0.01, 0.01, 0.01)).apply_translation([0.3, 0.0, 0.0])
    mesh = trimesh.util.concatenate(parts + [box])
    axis, trunk = np.concatenate(axes), np.concatenate(trunk)
    x = np.concatenate([np.arange(len(a)) * 0.002 for a in axes])
    tangent = np.tile([0.0, 0.0, -1.0], (len(axis), 1))
    d = np.linalg.norm(mesh.vertices[:, None] - axis[None], axis=2)
    sample = d.argmin(axis=1)
    vert = np.flatnonzero(d.min(axis=1) < 0.02)
    sample = sample[vert]
    rel = mesh.vertices[vert] - axis[sample]
    along = np.einsum("ij,ij->i", rel, tangent[sample])
    radial = np.sqrt(np.maximum((rel * rel).sum(axis=1) - along**2, 0.0))
    args = (vert, sample, along, radial, len(mesh.vertices), np.asarray(mesh.faces), trunk, x, 0.002)
    owner, radius = _crossings(*args)
    want_owner, want_radius = _numpy_crossings(*args)
    assert len(owner) > 500  # edges crossing planes of both icicles
    np.testing.assert_array_equal(owner, want_owner)
    np.testing.assert_array_equal(radius, want_radius)
    assert set(trunk[owner]) == {0, 1}
