"""Where fuse_fields runs the boolean union (icefarm.metaballs.union_region): the region holds
every cell that may meet the other surface, and the union comes out as with the wider
distance margin."""

from __future__ import annotations

import numpy as np
import pytest

from icefarm import metaballs as M
from icefarm.metaballs import fuse, union_region
from icefarm.metaballs.march import march_blocks


def _rods(tops, radius, voxel, n=12, length=0.036):
    """Tapering chains of balls hanging from ``tops`` (icicle-like rods), on a ``voxel`` lattice."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    centres = np.concatenate([np.asarray(top, float) + t * [0.002, -length, 0.001] for top in tops])
    radii = np.tile(radius * (1.0 - 0.6 * t.ravel()), len(tops))
    return M.sample_field(M.Balls(centres, radii, np.full(len(centres), M.LEVEL * np.e)), voxel)


def _slab(voxel):
    """A lumpy slab of balls under the rods: the glaze coat's stand-in, on its own lattice."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.02, 0.02, size=(60, 2))
    centres = np.c_[xy[:, 0], 0.004 * rng.standard_normal(60), xy[:, 1]]
    return M.sample_field(M.Balls(centres, np.full(60, 0.006), np.full(60, M.LEVEL * np.e)), voxel)


def _canonical(vertices, faces):
    """Each triangle from its least vertex on (orientation kept), rows sorted."""
    t = np.round(vertices[faces], 9)
    key = t[:, :, 0] * 1e6 + t[:, :, 1] * 1e3 + t[:, :, 2]
    turn = (np.argmin(key, axis=1)[:, None] + np.arange(3)) % 3
    t = np.take_along_axis(t, turn[:, :, None], axis=1).reshape(len(faces), 9)
    return t[np.lexsort(t.T[::-1])]


@pytest.mark.parametrize("fine, coarse, max_tiles", [(0.0004, 0.0016, None), (0.0006, 0.001, None),
                                                    (0.0004, 0.0016, 20_000), (0.0004, 0.0016, 3_000)])
def test_the_region_holds_every_cell_the_other_surface_meets(fine, coarse, max_tiles, monkeypatch):
    # Both ways round: a fine field against a coarse one's cells (four times: one or two of
    # them per tile and axis) and a coarse one against a fine one's (boxes on a dense grid:
    # summed where they span several tiles, marked where they span one or two, as on a
    # grid too small for single samples); on the smallest grids the fine field's blocks go
    # a group at a time.
    if max_tiles:
        monkeypatch.setattr(union_region, "_MAX_TILES", max_tiles)
    rods = _rods([[0.0, 0.006, 0.0]], 0.004, fine)
    slab = _slab(coarse)
    rng = np.random.default_rng(0)
    for field, other in ((rods, slab), (slab, rods)):
        lattice, faces = march_blocks(other.values, other.blocks, other.level)
        region = union_region.surface_region(field, other, lattice)
        assert region is not None
        # Points all over the other surface: every sample of the field's cell around each.
        w = rng.dirichlet(np.ones(3), size=len(faces))
        points = other.origin + np.einsum("kj,kjd->kd", w, lattice[faces]) * other.voxel
        cell = np.floor((points - field.origin) / field.voxel).astype(np.int64)
        for step in np.ndindex(2, 2, 2):
            assert region.holds(cell + np.array(step)).all()
        # ... and it is tighter than the distance margin it replaces.
        near = union_region.near_region(field, other.origin + lattice * other.voxel, union_region.margin(field, other))
        assert region.mask.sum() * region.tile**3 < near.mask.sum() * near.tile**3
        # The field's own faces inside it: those whose cell has its 8 samples held.
        own, own_faces = march_blocks(field.values, field.blocks, field.level)
        inner = union_region.inner_faces(own, own_faces, region)
        cells = np.floor(own[own_faces].min(axis=1)).astype(np.int64)
        expect = np.all([region.holds(cells + np.array(step)) for step in np.ndindex(2, 2, 2)], axis=0)
        assert 0 < inner.sum() < len(inner) and np.array_equal(inner, expect)


def test_fusing_on_the_surface_region_gives_the_margins_union(monkeypatch):
    a = _rods([[-0.01, 0.006, 0.0], [0.011, 0.006, 0.004]], 0.004, 0.0004)
    b = _slab(0.0016)
    monkeypatch.setattr(fuse, "union_meshes", lambda parts: pytest.fail("fell back to the whole-mesh union"))
    tight = fuse.fuse_fields(a, b)
    monkeypatch.setattr(fuse, "surface_region",
                        lambda field, other, lattice: union_region.near_region(
                            field, other.origin + lattice * other.voxel, union_region.margin(field, other)))
    wide = fuse.fuse_fields(a, b)
    x, y = _canonical(*tight), _canonical(*wide)
    assert x.shape == y.shape
    # Manifold cuts the same faces along the same lines; its new vertices may differ in the
    # last bits where the pieces it was handed differ.
    assert np.abs(x - y).max() < 1e-8


def test_inner_faces_are_those_whose_cell_keeps_its_samples():
    """`inner_faces` against its definition, cell by cell: a face is inner when each of the 8
    samples of its marching-cubes cell (the floor of its vertices' least coordinates) keeps
    its value in the restricted field: in a tile of the region, or in no block at all;
    vertices of no marching (NaN) are never inner."""
    rng = np.random.default_rng(3)
    tile, block = 4, 8
    blocks = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1], [2, 1, 0], [1, 2, 2]])
    mask = rng.random((len(blocks), 2, 2, 2)) < 0.6
    index = np.full((5, 5, 5), -1)  # with a border of no blocks
    index[tuple(blocks.T + 1)] = np.arange(len(blocks))
    region = union_region.Region(mask, tile, index, np.full(3, -1))
    cells = rng.integers(-3, 20, (4000, 3))
    # a triangle in each cell, its vertices at the cell's corners or between them
    offset = np.where(rng.random((4000, 3, 3)) < 0.5, rng.random((4000, 3, 3)), rng.integers(0, 2, (4000, 3, 3)))
    lattice = (cells[:, None, :] + offset).reshape(-1, 3)
    lattice[rng.random(len(lattice)) < 0.01] = np.nan
    faces = np.arange(len(lattice)).reshape(-1, 3)
    inner = union_region.inner_faces(lattice, faces, region)

    def kept(s):
        b = s // block + 1
        if (b < 0).any() or (b > 4).any() or index[tuple(b)] < 0:
            return True
        return bool(mask[(index[tuple(b)], *((s % block) // tile))])

    for k, f in enumerate(faces):
        v = lattice[f]
        if not np.isfinite(v).all():
            assert not inner[k]
            continue
        cell = np.floor(v).astype(int).min(axis=0)
        assert inner[k] == all(kept(cell + np.array(d)) for d in np.ndindex(2, 2, 2))
    assert 0 < inner[np.isfinite(lattice[faces]).all(axis=(1, 2))].mean() < 1


def test_values_at_reads_the_blocks_and_zero_elsewhere():
    rng = np.random.default_rng(5)
    block = 4
    blocks = np.unique(rng.integers(0, 5, (30, 3)), axis=0)
    values = rng.random((len(blocks), block, block, block)).astype(np.float32)
    field = M.Field(np.zeros(3), 0.001, 0.5, blocks, values)
    samples = rng.integers(-6, 26, (3000, 3))
    where = {tuple(b): k for k, b in enumerate(blocks)}
    want = [values[(where[tuple(s // block)], *(s % block))] if tuple(s // block) in where else 0.0 for s in samples]
    assert np.array_equal(M.field.values_at(field, samples), np.array(want, dtype=np.float32))
