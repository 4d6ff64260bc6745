"""The compiled slides (`icefarm.stages.slide_kernel`) against the NumPy slides they
replaced, kept here as the reference: the same trajectories to Embree's float32."""

import numpy as np
import pytest
import trimesh

from icefarm.geometry import unit
from icefarm.job import Stage, run_stages
from icefarm.mesh import prepare
from icefarm.params import defaults, resolve
from icefarm.stages import turtles
from icefarm.stages.trajectories import TrajectoryOptions, grow_trajectories

G = np.array([0.0, -1.0, 0.0])


def numpy_slide(self, t, rows, hits, face):
    """All sliding turtles step together, in NumPy."""
    normal = self.facing(face, t.heading[rows])
    pos = hits + self.lift * normal
    rises = (pos - t.pos[rows]) @ self.g < 1e-3 * self.step
    pos[rises] = t.pos[rows[rises]]
    self.record(t, rows[~rises], pos[~rises])
    limit = int(4 * np.linalg.norm(self.mesh.extents) / self.step) + 1
    sliding = np.ones(len(rows), dtype=bool)
    for _ in range(limit):
        done = normal @ self.g >= self.cos_dl
        along = self.g - (normal @ self.g)[:, None] * normal
        stuck = ~done & (np.linalg.norm(along, axis=1) < 1e-3)
        t.alive[rows[stuck & sliding]] = False
        self.release(t, rows[done & sliding], pos[done & sliding])
        sliding &= ~done & ~stuck
        if not sliding.any():
            return
        k = np.flatnonzero(sliding)
        target = pos[k] + self.step * unit(along[k])
        back, below = self.cast(target, -normal[k])
        fell_off = back > self.step + self.lift
        on = ~fell_off
        new_normal = normal[k].copy()
        if on.any():
            new_normal[on] = self.facing(below[on], -normal[k][on])
        surface = target - np.where(fell_off, 0.0, back)[:, None] * normal[k]
        moved = np.where(on[:, None], surface + self.lift * new_normal, target)
        chord = moved - pos[k]
        span = np.linalg.norm(chord, axis=1)
        reach, wall = self.cast(pos[k], unit(chord))
        cut = reach < span + self.eps
        if cut.any():
            moved[cut] = pos[k][cut] + np.maximum(reach[cut] - self.lift, 0.0)[:, None] * unit(chord[cut])
            new_normal[cut] = self.facing(wall[cut], chord[cut])
            fell_off &= ~cut
        stalled = (moved - pos[k]) @ self.g < 0.05 * self.step
        t.alive[rows[k[stalled]]] = False
        sliding[k[stalled]] = False
        pos[k] = moved
        normal[k] = new_normal
        self.record(t, rows[k[~stalled]], pos[k[~stalled]])
        fell_off &= ~stalled
        self.release(t, rows[k[fell_off]], pos[k[fell_off]])
        sliding[k[fell_off]] = False
    t.alive[rows[sliding]] = False


def _ledges(open_mesh):
    """Drips under a shelf above a roof tilted 25 degrees: the icicles meet the roof and
    slide down it; ``open_mesh``: the roof's top is missing (they slide on its underside)."""
    shelf = trimesh.creation.box((0.3, 0.02, 0.1))
    shelf.apply_translation((0.0, 0.25, 0.0))
    roof = trimesh.creation.box((0.4, 0.02, 0.2))
    roof.apply_transform(trimesh.transformations.rotation_matrix(np.radians(25.0), [0, 0, 1]))
    if open_mesh:
        roof.update_faces(roof.face_normals[:, 1] < 0.5)
    mesh = trimesh.util.concatenate([shelf, roof])
    x = np.linspace(-0.12, 0.12, 9)
    starts = np.c_[x, np.full_like(x, 0.24 - 1e-4), np.zeros_like(x)]
    return mesh, starts, np.tile(G, (len(x), 1)), np.full(len(x), 0.5), G


def _bunny(shared_mesh):
    p = resolve({"storm.mode": "relative"})
    result = run_stages(prepare(shared_mesh("stanford-bunny.obj"), 0.3), p, 1, until=Stage.DRIPS)
    mesh, drips = result.mesh, result.drips
    return mesh, drips.positions, mesh.face_normals[drips.faces], drips.water, np.asarray(p.water.gravity, float)


@pytest.mark.parametrize("which", ["closed", "open", "bunny"])
def test_compiled_slides_grow_the_numpy_slides_trajectories(monkeypatch, shared_mesh, which):
    mesh, starts, normals, water, g = _bunny(shared_mesh) if which == "bunny" else _ledges(which == "open")
    assert mesh.is_watertight == (which == "closed")
    options = TrajectoryOptions(gravity=g, **{**defaults()["trajectories"], "drip_limit": 75.0,
                                              "division_probability": 0.3, "curve_angle": 30.0,
                                              "contact": "slide"})
    calls = []
    compiled_slide = turtles._Grower.slide
    monkeypatch.setattr(turtles._Grower, "slide", lambda *a: (calls.append(len(a[2])), compiled_slide(*a))[1])
    ours = [grow_trajectories(mesh, starts, normals, water, np.random.default_rng(s), options) for s in range(3)]
    monkeypatch.setattr(turtles._Grower, "slide", numpy_slide)
    reference = [grow_trajectories(mesh, starts, normals, water, np.random.default_rng(s), options) for s in range(3)]
    assert sum(calls) > 20  # turtles did slide
    for a, b in zip(ours, reference):
        assert np.array_equal(a.branch_offsets, b.branch_offsets)
        assert np.array_equal(a.branch_parent, b.branch_parent)
        assert np.abs(a.points - b.points).max() < 1e-6
