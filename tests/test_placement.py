"""Where an object stands: grounded objects rest on the ground, icicles stop at it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from icefarm import params
from icefarm.errors import InputError
from icefarm.farm.manifest import load_manifest
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.placement import ground_height, sole_vertices, stop_at_ground
from icefarm.stages.trajectories import TrajectoryResult

G = np.array([0.0, -1.0, 0.0])


def test_an_icicle_that_would_reach_the_ground_stops_at_it():
    trunk = np.column_stack([np.zeros(11), np.linspace(0.0, -0.1, 11), np.zeros(11)])
    short = trunk[:3] + [0.05, 0.0, 0.0]
    traj = TrajectoryResult(np.vstack([trunk, short]), np.array([0, 11, 14]), np.array([0, 1]), np.array([-1, -1]))
    cut = stop_at_ground(traj, G, floor=-0.055, margin=0.005)
    assert cut.n_branches == 2
    assert cut.branch(0)[:, 1].min() == pytest.approx(-0.05)  # ends exactly at floor + margin
    assert np.array_equal(cut.branch(1), short)  # clear of the ground: untouched
    assert cut.cut == pytest.approx([0.05, 0.0])  # what the ground took, for the profile
    branch = TrajectoryResult(trunk[6:], np.array([0, 5]), np.array([0]), np.array([-1]))
    assert len(stop_at_ground(branch, G, floor=-0.055, margin=0.005).branch(0)) == 0
    assert stop_at_ground(traj, G, floor=-1.0, margin=0.005) is traj


def test_the_sole_is_the_bottom_of_the_object():
    box = trimesh.creation.box((0.2, 0.3, 0.2))
    sole = sole_vertices(box.vertices, G, 0.02)
    assert np.all(box.vertices[sole, 1] == pytest.approx(-0.15)) and sole.sum() == 4
    assert ground_height(box.vertices, G) == pytest.approx(-0.15)


def _ring_on_legs(tmp_path):
    """A ring whose underside drips, on legs that reach the ground 0.1 m below it."""
    ring = trimesh.creation.annulus(r_min=0.08, r_max=0.12, height=0.03)
    ring.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    legs = [trimesh.creation.box((0.02, 0.12, 0.02), trimesh.transformations.translation_matrix([x, -0.075, z]))
            for x, z in ((0.1, 0.0), (-0.1, 0.0), (0.0, 0.1))]
    mesh = trimesh.util.concatenate([ring, *legs])
    path = tmp_path / "stand.ply"
    mesh.export(path)
    return path


@pytest.mark.parametrize("placement", ["ground", "hanging"])
def test_grounded_icicles_stop_at_the_ground_and_hanging_ones_do_not(tmp_path, placement):
    path = _ring_on_legs(tmp_path)
    p = params.resolve({"storm.mode": "relative", "water.rays": 1500, "drips.count": 12,
                        "trajectories.length_scale": 20.0, "proxy.mode": "never"})
    spec = JobSpec("stand", str(path), 0.15, p, seed=1, placement=placement)
    outcome = run_job(spec, tmp_path / placement, until=Stage.TRAJECTORIES)
    assert outcome.status == "done", outcome.error
    icicles = json.loads((tmp_path / placement / "trajectories.json").read_text())["icicles"]
    lowest = min(min(pt[1] for pt in b["points"]) for ic in icicles for b in ic["branches"] if b["points"])
    ground = -0.075  # the legs' feet: the stand is 0.15 m tall, centred on its bounding box
    if placement == "ground":
        assert lowest >= ground + p.surface.tip_radius - 1e-9
    else:
        assert lowest < ground  # long icicles hang past the feet


def test_manifest_placement_defaults_to_ground_and_refuses_others(tmp_path):
    text = "name: t\nobjects:\n  - {mesh: generator:teapot, size_m: 0.3%s}\n"
    (tmp_path / "a.yaml").write_text(text % "")
    assert load_manifest(tmp_path / "a.yaml").objects[0].placement == "ground"
    (tmp_path / "b.yaml").write_text(text % ", placement: hanging")
    assert load_manifest(tmp_path / "b.yaml").objects[0].placement == "hanging"
    (tmp_path / "c.yaml").write_text(text % ", placement: floating")
    with pytest.raises(InputError, match="placement"):
        load_manifest(tmp_path / "c.yaml")


@pytest.mark.slow
@pytest.mark.parametrize("placement", ["ground", "hanging"])
def test_a_grounded_object_rests_on_the_ground_plane_of_its_scene(tmp_path, placement, sphere):
    import xml.etree.ElementTree as ET

    path = tmp_path / "sphere.ply"
    sphere.export(path)
    config = tmp_path / "tiny.yaml"
    config.write_text("resolution: [40, 30]\nspp: 2\nmax_depth: 4\n")
    p = params.resolve({"water.rays": 1500, "drips.count": 8, "drips.drip_limit": 80, "glaze.mode": "none"})
    spec = JobSpec("sphere", str(path), 0.3, p, seed=2, render=str(config), placement=placement)
    outcome = run_job(spec, tmp_path / placement)
    assert outcome.status == "done", outcome.error
    job = tmp_path / placement
    shape = next(s for s in ET.parse(job / "scene.xml").getroot().iter("shape") if s.get("id") == "ground")
    matrix = np.array(shape.find("transform/matrix").get("value").split(), dtype=float).reshape(4, 4)
    ground = matrix[1, 3]  # y of the ground rectangle's centre: gravity is -y
    lowest = trimesh.load(job / "object.ply").vertices[:, 1].min()
    ice_lowest = trimesh.load(job / "ice.ply").vertices[:, 1].min()
    if placement == "ground":
        assert abs(lowest - ground) <= 0.001  # the object stands on it
        assert ice_lowest >= ground - 1e-6     # no ice below the ground
        assert json.loads((job / "done.json").read_text())["placement"] == "ground"
        assert abs(json.loads((job / "timings.json").read_text())["ground_gap_mm"]) <= 1.0
    else:
        assert ground < min(lowest, ice_lowest)  # the ground below the lowest ice
        gap = json.loads((job / "timings.json").read_text())["ground_gap_mm"]
        assert gap == pytest.approx((lowest - ground) * 1000, abs=0.01)
