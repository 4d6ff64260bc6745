"""Ice below and between the icicles: landing points, mounds, stalagmites, columns, curtains."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh

from icefarm import metaballs as M, params
from icefarm.errors import InputError
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.spatial import ray_caster
from icefarm.stages import surface as S
from icefarm.stages.drips import DripResult
from icefarm.stages.landing import LandingOptions, find_landings
from icefarm.stages.surface.curtains import curtain_balls
from icefarm.stages.surface.ground_ice import STALAGMITE_TOP, ground_ice_balls
from icefarm.stages.trajectories import TrajectoryResult

G = np.array([0.0, -1.0, 0.0])
UP = -G
TIP = 0.00244


def _p(**changes):
    return params.resolve({k.replace("__", "."): v for k, v in changes.items()})


def _step():
    """An eave slab (underside at 0.30 m) over a ledge (top at 0.10 m, x > 0) standing on the
    ground (y = 0): icicles at x < 0 drip onto the ground, at x > 0 onto the ledge."""
    eave = trimesh.creation.box([0.3, 0.02, 0.1], trimesh.transformations.translation_matrix([0, 0.31, 0]))
    ledge = trimesh.creation.box([0.1, 0.1, 0.1], trimesh.transformations.translation_matrix([0.07, 0.05, 0]))
    return trimesh.util.concatenate([eave, ledge])


def _drips(mesh, traj, water):
    points = traj.points[traj.branch_offsets[:-1]]
    closest, _, face = trimesh.proximity.closest_point(mesh, points)
    return DripResult(np.zeros(0, int), closest, mesh.face_normals[face], np.asarray(water, float), face)


@pytest.fixture
def eave_icicles(surface_kit):
    """Five trunks 2.5 cm apart under the eave (x < 0, over the ground), lengths 6-16 cm,
    and one over the ledge; and their water."""
    starts = [[-0.12 + 0.025 * i, 0.3, 0.0] for i in range(5)] + [[0.07, 0.3, 0.0]]
    lengths = [0.10, 0.16, 0.06, 0.12, 0.08, 0.10]
    return surface_kit.straight(starts, lengths), np.array([0.12, 0.2, 0.08, 0.15, 0.1, 0.12])


def _landings(obj, traj, water, merge=0.02, runoff=0.5, floor=0.0):
    return find_landings(traj, water, G, LandingOptions(runoff, merge, floor), cast=ray_caster(obj),
                         face_normals=obj.face_normals)


def test_every_landing_point_lies_on_a_surface_straight_below_its_tip(eave_icicles):
    obj = _step()
    traj, water = eave_icicles
    land = _landings(obj, traj, water, merge=0.0)
    assert len(land) == 6 and land.on_ground.sum() == 5
    ground = land.positions[land.on_ground]
    assert np.allclose(ground @ UP, 0.0)
    ledge = land.positions[~land.on_ground]
    _, distance, _ = trimesh.proximity.closest_point(obj, ledge)
    assert distance.max() < 1e-6 and np.allclose(ledge @ UP, 0.1, atol=1e-6)
    assert np.allclose(land.normals, UP)
    # Below its tip, along gravity: same horizontal place, lower, by the gap.
    tips = traj.points[traj.branch_offsets[1:] - 1]
    for b, k in enumerate(land.branch_landing):
        horizontal = (tips[b] - land.positions[k]) - ((tips[b] - land.positions[k]) @ UP) * UP
        assert np.linalg.norm(horizontal) < 1e-9
        assert tips[b] @ UP - land.positions[k] @ UP == pytest.approx(land.gaps[k])
        assert land.gaps[k] > 0
    assert land.water == pytest.approx(0.5 * water[land.icicles])


def test_a_hanging_object_loses_the_water_that_falls_past_it(eave_icicles):
    obj = _step()
    traj, water = eave_icicles
    land = find_landings(traj, water, G, LandingOptions(0.5, 0.0), cast=ray_caster(obj),
                         face_normals=obj.face_normals)
    assert len(land) == 1 and not land.on_ground[0]  # only the ledge catches any
    assert (land.branch_landing == -1).sum() == 5


def test_merged_landing_points_keep_the_merge_distance_and_the_water(surface_kit):
    rng = np.random.default_rng(3)
    starts = np.c_[rng.uniform(-0.1, 0.1, 60), np.full(60, 0.3), rng.uniform(-0.1, 0.1, 60)]
    traj = surface_kit.straight(starts, rng.uniform(0.02, 0.2, 60))
    water = rng.uniform(0.01, 0.2, 60)
    merge = 0.03
    land = find_landings(traj, water, G, LandingOptions(0.4, merge, 0.0))
    assert 1 < len(land) < 60
    d = np.linalg.norm(land.positions[:, None] - land.positions[None], axis=2)
    assert d[np.triu_indices(len(land), 1)].min() >= merge
    assert land.water.sum() == pytest.approx(0.4 * water.sum())
    spots = starts * [1, 0, 1]  # each tip's own landing point on the ground
    for b, k in enumerate(land.branch_landing):
        assert np.linalg.norm(spots[b] - land.positions[k]) <= merge
        assert traj.points[traj.branch_offsets[b + 1] - 1] @ UP >= land.tips[k] @ UP - 1e-12  # the lowest tip
    assert np.allclose(land.gaps, land.tips @ UP - land.positions @ UP)


def test_branch_tips_share_their_icicles_water_by_length():
    pts = np.array([[0, 0.3, 0], [0, 0.2, 0], [0, 0.2, 0], [0.05, 0.15, 0]], float)
    traj = TrajectoryResult(pts, np.array([0, 2, 4]), np.array([0, 0]), np.array([-1, 0]))
    land = find_landings(traj, np.array([0.1]), G, LandingOptions(1.0, 0.0, 0.0))
    trunk, branch = 0.1, np.hypot(0.05, 0.05)
    assert land.water[land.branch_landing] == pytest.approx([0.1 * trunk / (trunk + branch),
                                                             0.1 * branch / (trunk + branch)])


def test_no_stalagmite_passes_its_tip_and_the_close_ones_become_columns(eave_icicles):
    obj = _step()
    traj, water = eave_icicles
    land = _landings(obj, traj, water)
    surface = _p(surface__voxel_size=0.0015).surface
    gi = _p(ground_ice__mode="stalagmites", ground_ice__height_scale=2.5).ground_ice
    ice = ground_ice_balls(land, gi, surface, G, np.random.default_rng(0), cast=ray_caster(obj), floor=0.0)
    assert (ice.heights <= land.gaps + 1e-12).all()
    assert ice.columns.sum() == 3 and (~ice.columns & (ice.heights > 0)).sum() == 3
    assert np.allclose(ice.heights[ice.columns], land.gaps[ice.columns])
    assert ice.columns[~land.on_ground].all()  # the ledge's, 10 cm under its tip, with 15 cm of water
    verts, faces = M.polygonize(ice.balls, surface.voxel_size)
    assert trimesh.Trimesh(verts, faces).is_watertight
    # On the mesh: the ice of each free stalagmite (alone: wide neighbours overlap) stops at
    # its height, under its tip.
    for k in np.flatnonzero((ice.heights > 0) & ~ice.columns):
        one = dataclasses.replace(land, **{f: getattr(land, f)[k:k + 1] for f in
                                           ("positions", "normals", "water", "tips", "gaps", "icicles", "on_ground")})
        alone = ground_ice_balls(one, gi, surface, G, np.random.default_rng(0), cast=ray_caster(obj), floor=0.0)
        verts, _ = M.polygonize(alone.balls, surface.voxel_size)
        rel = verts - land.positions[k]
        near = np.linalg.norm(rel - np.outer(rel @ UP, UP), axis=1) < STALAGMITE_TOP * TIP
        top = (rel[near] @ UP).max()
        assert top == pytest.approx(ice.heights[k], abs=2 * surface.voxel_size)
        assert top < land.gaps[k] - TIP
    # A column is ice all the way up into the icicle's drop; a free one leaves the air under it.
    under_tip = land.tips - 1.5 * TIP * UP
    assert (_field(ice.balls, under_tip[ice.columns]) > M.LEVEL).all()
    assert (_field(ice.balls, under_tip[~ice.columns]) < M.LEVEL).all()


def _field(balls, points):
    d2 = ((points[:, None, :] - balls.centers[None]) ** 2).sum(axis=2)
    return (balls.weights * np.exp(-d2 / balls.widths**2)).sum(axis=1)


def test_mounds_mode_spreads_caps_without_stalagmites(eave_icicles):
    obj = _step()
    traj, water = eave_icicles
    land = _landings(obj, traj, water)
    gi = _p(ground_ice__mode="mounds").ground_ice
    ice = ground_ice_balls(land, gi, _p().surface, G, np.random.default_rng(0), cast=ray_caster(obj), floor=0.0)
    assert len(ice.balls) > 0 and not ice.heights.any() and not ice.columns.any()
    assert ice.mound_radius == pytest.approx(gi.spread * land.water) and ice.mound_radius.all()
    # Caps stay low: within a quarter of their radius of the surface, above or below.
    centres = ice.balls.centers
    assert (centres @ UP).min() > -1e-9 and (centres @ UP).max() < 0.1 + 1e-6


def test_curtain_area_only_between_trunks_closer_than_the_curtain(surface_kit):
    starts = [[0.0, 0.3, 0.0], [0.025, 0.3, 0.0], [0.1, 0.3, 0.0]]
    traj = surface_kit.straight(starts, [0.12, 0.09, 0.12])
    surface = _p(surface__growth_ratio=0.02, surface__voxel_size=0.0015).surface
    near = curtain_balls(traj, dataclasses.replace(surface, curtain=0.03), G)
    assert near.pairs == 1 and near.area > 0 and len(near.balls) > 0
    # About the span outside the trunks times the shorter reach, less the drape.
    assert near.area < 0.025 * 0.09
    far = curtain_balls(traj, dataclasses.replace(surface, curtain=0.02), G)
    assert far.pairs == 0 and far.area == 0 and len(far.balls) == 0
    assert curtain_balls(traj, dataclasses.replace(surface, curtain=0.0), G).area == 0
    # Neighbours only: with a reach over all three, the outer pair is left to the middle one.
    assert curtain_balls(traj, dataclasses.replace(surface, curtain=0.2), G).pairs == 2


@pytest.fixture
def build(surface_kit):
    """``build(obj, traj, water, p, **kw)``: stage 4 on ``obj`` without glaze water, drips at the trunks' roots."""

    def ice(obj, traj, water, p, **kw):
        inputs = S.IceInputs(obj, obj, surface_kit.dry(obj), _drips(obj, traj, water), traj, **kw)
        return S.build_ice(inputs, p.surface, p.glaze, G, np.random.default_rng(0))

    return ice


def test_ice_with_stalagmites_mounds_and_curtains_stays_one_watertight_mesh(eave_icicles, build):
    obj = _step()
    traj, water = eave_icicles
    p = _p(surface__voxel_size=0.0015, surface__curtain=0.03, glaze__mode="none", surface__growth_ratio=0.03)
    land = _landings(obj, traj, water)
    gi = dataclasses.replace(p.ground_ice, mode="stalagmites")
    ground = ground_ice_balls(land, gi, p.surface, G, np.random.default_rng(1), cast=ray_caster(obj), floor=0.0)
    ice = build(obj, traj, water, p, extra_balls=ground.balls)
    m = trimesh.Trimesh(ice.vertices, ice.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert ice.curtain_area > 0
    plain = build(obj, traj, water, _p(surface__voxel_size=0.0015, glaze__mode="none", surface__growth_ratio=0.03))
    assert m.volume > trimesh.Trimesh(plain.vertices, plain.faces).volume
    assert (ice.vertices @ UP).min() < 0.05  # ice on the ground, not only on the icicles


def test_mode_none_and_no_curtain_leave_the_ice_exactly_unchanged(eave_icicles, build):
    obj = _step()
    traj, water = eave_icicles
    p = _p(surface__voxel_size=0.002)
    before = build(obj, traj, water, p.updated({"surface.curtain": params.defaults()["surface"]["curtain"]}))
    land = _landings(obj, traj, water)
    none = ground_ice_balls(land, p.ground_ice, p.surface, G, np.random.default_rng(0))
    assert len(none.balls) == 0
    after = build(obj, traj, water, p, extra_balls=none.balls)
    assert np.array_equal(before.vertices, after.vertices) and np.array_equal(before.faces, after.faces)
    assert after.curtain_area == 0


def test_parameters_are_declared_with_domains():
    p = params.resolve({})
    assert p.ground_ice.mode == "none" and p.surface.curtain == 0.0
    with pytest.raises(InputError, match="ground_ice.mode"):
        params.resolve({"ground_ice.mode": "pillars"})
    with pytest.raises(InputError, match="ground_ice.runoff"):
        params.resolve({"ground_ice.runoff": 1.5})
    with pytest.raises(InputError, match="surface.curtain"):
        params.resolve({"surface.curtain": -0.01})


def test_a_roof_job_writes_landing_json_and_reports_the_ground_ice(tmp_path):
    values = {"storm.mode": "relative", "drips.count": 8, "surface.voxel_size": 0.003, "glaze.mode": "none",
              "ground_ice.mode": "stalagmites", "surface.curtain": 0.04}
    spec = JobSpec("roof", "generator:roof", 0.4, params.resolve(values), seed=2)
    out = tmp_path / "job"
    assert run_job(spec, out, until=Stage.SURFACE).status == "done"
    landing = json.loads((out / "landing.json").read_text())["landing_points"]
    timings = json.loads((out / "timings.json").read_text())
    done = json.loads((out / "done.json").read_text())
    assert "landing.json" in done["artifacts"]
    assert timings["landing_points"] == len(landing) > 0
    assert {"landing", "ground_ice"} <= set(timings["seconds"]) and timings["seconds"]["landing"] < 1.0
    heights = [p["stalagmite_height"] for p in landing]
    assert timings["stalagmites"] == sum(h > 0 for h in heights)
    assert all(p["stalagmite_height"] <= p["gap"] + 1e-9 for p in landing)
    ground = [p["position"][1] for p in landing if p["on_ground"]]
    assert ground and max(ground) - min(ground) < 1e-9  # all on the one ground plane
    assert "curtain_area_m2" in timings
    ice = trimesh.load(out / "ice.ply", process=False)
    assert ice.is_watertight
