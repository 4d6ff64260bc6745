"""One job through the pipeline: ground clearance, the stage cache, failures that lose nothing."""

import json
import sys

import numpy as np
import pytest

from icefarm import params
from icefarm.job.pipeline import JobSpec, Stage, run_job


def sphere_job(tmp_path, sphere, **values):
    path = tmp_path / "sphere.ply"
    sphere.export(path)
    p = params.resolve({"storm.mode": "relative", "water.rays": 2000, "drips.count": 40, "drips.drip_limit": 80,
                        **values})
    return JobSpec("sphere", str(path), 0.3, p, seed=3)


def drip_heights(job_dir):
    drips = json.loads((job_dir / "drips.json").read_text())["drip_points"]
    return np.array([d["position"][1] for d in drips])


def test_ground_clearance_keeps_icicles_off_the_resting_bottom(tmp_path, sphere):
    low = run_job(sphere_job(tmp_path, sphere, **{"drips.ground_clearance": 0.0}), tmp_path / "a",
                  until=Stage.DRIPS)
    high = run_job(sphere_job(tmp_path, sphere, **{"drips.ground_clearance": 0.2}), tmp_path / "b",
                   until=Stage.DRIPS)
    assert low.status == high.status == "done"
    bottom = -0.15
    assert drip_heights(tmp_path / "a").min() < bottom + 0.2 * 0.3
    heights = drip_heights(tmp_path / "b")
    assert len(heights) == 40 and heights.min() >= bottom + 0.2 * 0.3 - 1e-9


def test_cache_reuses_upstream_stages_when_only_trajectories_change(tmp_path, sphere):
    cache = tmp_path / "cache"
    first = run_job(sphere_job(tmp_path, sphere), tmp_path / "a", cache, until=Stage.TRAJECTORIES)
    second = run_job(sphere_job(tmp_path, sphere, **{"trajectories.curve_angle": 20}), tmp_path / "b", cache,
                     until=Stage.TRAJECTORIES)
    assert first.reused == ()
    assert set(second.reused) == {"water", "drips"}
    a = json.loads((tmp_path / "a" / "trajectories.json").read_text())
    b = json.loads((tmp_path / "b" / "trajectories.json").read_text())
    assert a != b
    assert (tmp_path / "a" / "drips.json").read_text() == (tmp_path / "b" / "drips.json").read_text()


def test_a_failed_job_writes_error_json_and_no_done_json(tmp_path, sphere):
    spec = sphere_job(tmp_path, sphere)
    job_dir = tmp_path / "job"
    assert run_job(spec, job_dir, until=Stage.DRIPS).status == "done"
    (tmp_path / "sphere.ply").write_bytes(b"not a mesh")
    outcome = run_job(spec, job_dir, until=Stage.DRIPS)
    assert outcome.status == "failed" and outcome.failed_stage == "prepare"
    assert not (job_dir / "done.json").exists(), "a stale done.json must not survive a failed rerun"
    error = json.loads((job_dir / "error.json").read_text())
    assert error["stage"] == "prepare" and "sphere.ply" in error["message"] and error["traceback"]


def test_cache_entries_round_trip_every_stage_result_without_pickle(tmp_path):
    """Each cached stage result comes back equal, from an .npz that holds no pickle; an
    entry naming a type outside icefarm is refused, not imported."""
    import dataclasses
    import enum

    import numpy as np

    from icefarm.generators import generate
    from icefarm.job import run_stages
    from icefarm.job.codec import decode, encode
    from icefarm.mesh import prepare

    prepared = prepare(generate("roof"), 0.4)
    quick = {"surface.voxel_size": 0.006, "glaze.voxel_size": 0.024, "storm.max_icicles": 4, "storm.flow_edge": 0.05}
    r = run_stages(prepared, params.resolve(quick), 0)  # coarse, four icicles: quick
    results = [r.water, r.drips, r.trajectories, r.ice]

    def same(a, b):
        if dataclasses.is_dataclass(a):
            assert type(a) is type(b)
            for f in dataclasses.fields(a):
                same(getattr(a, f.name), getattr(b, f.name))
        elif isinstance(a, np.ndarray):
            assert b.dtype == a.dtype and np.array_equal(a, b, equal_nan=True)
        elif isinstance(a, (tuple, list)):
            assert type(a) is type(b) and len(a) == len(b)
            for x, y in zip(a, b):
                same(x, y)
        elif isinstance(a, float) and np.isnan(a):
            assert np.isnan(b)
        else:
            assert a == b and type(a) is type(b) or isinstance(a, enum.Enum) and a is b

    for result in results:
        data = encode(result)
        with np.load(__import__("io").BytesIO(data), allow_pickle=False) as npz:  # no pickle inside
            assert all(npz[k].dtype != object for k in npz.files)
        same(result, decode(data))
    import pytest

    from icefarm.job.codec import _decode

    for forged in ({"dataclass": "subprocess:Popen", "fields": {}}, {"enum": "os:system", "value": 1},
                   {"dataclass": "icefarm.job.codec:encode", "fields": {}}):
        with pytest.raises(ValueError):
            _decode(forged, {})


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_freed_heap_goes_back_to_the_system_before_the_render():
    """Small temporaries freed between survivors stay mapped (the heap's top is not free, so
    glibc cannot shrink it); the pipeline hands their pages back before the render."""
    from icefarm.job.render import return_freed_memory

    def resident_mb():
        return next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmRSS")) / 1024

    chunks = [bytearray(2000) for _ in range(100_000)]  # past pymalloc: glibc's heap, 200 MB
    survivors = chunks[::8]
    del chunks
    before = resident_mb()
    return_freed_memory()
    assert before - resident_mb() > 60  # 175 MB freed in 14 kB holes (measured: 119 MB returned)
    assert len(survivors) == 12_500


def test_trajectories_json_keeps_the_branch_tree_when_an_icicles_branches_are_apart(tmp_path):
    """trajectories.json names a parent by its place in its icicle's list of branches: with
    branches stored icicle 0, 1, 0, 1, 0 (a fork's branches come after other trunks, as on
    the car and the 3 m house), counting from the icicle's first branch named parents past
    the list's end."""
    from icefarm.artifacts import trajectories_from_json, trajectories_to_json
    from icefarm.stages.trajectories import TrajectoryResult

    tops = np.array([[0, 1, 0], [1, 1, 0], [0, 0.9, 0], [1, 0.9, 0], [0.01, 0.8, 0]], dtype=float)
    pts = np.repeat(tops, 2, axis=0) - np.tile([[0, 0, 0], [0, 0.05, 0]], (5, 1))
    traj = TrajectoryResult(pts, np.arange(0, 11, 2), np.array([0, 1, 0, 1, 0]), np.array([-1, -1, 0, 1, 2]))
    path = tmp_path / "trajectories.json"
    path.write_text(json.dumps(trajectories_to_json(traj)))
    back = trajectories_from_json(path)  # icicle 0's branches (0, 2, 4), then icicle 1's (1, 3)
    np.testing.assert_array_equal(back.branch_parent, [-1, 0, 1, -1, 3])
    np.testing.assert_array_equal(back.branch_icicle, [0, 0, 0, 1, 1])
    for new, old in enumerate([0, 2, 4, 1, 3]):
        np.testing.assert_allclose(back.branch(new), traj.branch(old))
