"""One chain of stages: what a job runs is what bench, Table 2 and the tests run."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from icefarm import params
from icefarm.bench import stage_timings
from icefarm.chain import Stage, run_stages
from icefarm.mesh import prepare
from icefarm.pipeline import JobSpec, run_job

SMALL = {"water.rays": 1500, "drips.count": 6, "glaze.mode": "none", "surface.voxel_size": 0.003}


def _bowl(tmp_path):
    path = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=3).export(path)
    return path


def test_a_job_and_the_bare_chain_give_the_same_stages(tmp_path):
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    run_job(JobSpec("ball", str(path), 0.3, p, seed=4), tmp_path / "job", until=Stage.TRAJECTORIES)
    bare = run_stages(prepare(str(path), 0.3, p["water"]["gravity"]), p, 4, until=Stage.TRAJECTORIES)
    job = json.loads((tmp_path / "job" / "drips.json").read_text())["drip_points"]
    assert len(job) == len(bare.drips.positions) > 0
    np.testing.assert_allclose([d["position"] for d in job], bare.drips.positions, atol=1e-9)
    assert bare.ice is None and bare.trajectories.n_branches >= len(job)


def test_steps_come_in_order_and_stop_where_asked(tmp_path):
    p = params.resolve(SMALL)
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p["water"]["gravity"])
    seen, files = [], []
    result = run_stages(prepared, p, 0, until=Stage.DRIPS, step=lambda name, key, work: seen.append(name) or work(),
                        on_stage=lambda name, r: files.append((name, r.drips is not None)))
    assert seen == ["water", "drips"] and files == [("water", False), ("drips", True)]
    assert result.trajectories is None and result.flow is result.mesh


@pytest.mark.slow
def test_a_proxy_run_hangs_its_icicles_from_the_object(tmp_path):
    p = params.resolve({**SMALL, "proxy.mode": "always"})
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p["water"]["gravity"])
    seen = []
    result = run_stages(prepared, p, 0, until=Stage.TRAJECTORIES,
                        step=lambda name, key, work: seen.append(name) or work())
    assert seen[:2] == ["proxy", "water"] and result.flow is not result.mesh and result.proxy_reason
    distance = np.abs(trimesh.proximity.signed_distance(result.mesh, result.drips.positions))
    assert distance.max() < 1e-6


def test_the_benchmark_times_the_jobs_chain(tmp_path):
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    runs = stage_timings(str(path), 0.3, p, repeat=1, surface=True)
    bare = run_stages(prepare(str(path), 0.3, p["water"]["gravity"]), p, 0)
    assert set(runs.seconds) == {"water", "drips", "trajectories", "surface"}
    assert runs.icicles == len(bare.drips.positions) and runs.ice_faces == len(bare.ice.faces)


def test_an_unknown_override_is_refused(tmp_path):
    p = params.resolve(SMALL)
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p["water"]["gravity"])
    with pytest.raises(ValueError, match="surface"):
        run_stages(prepared, p, 0, overrides={"surface": "ice.ply"})
