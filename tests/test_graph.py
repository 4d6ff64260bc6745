"""One declared graph, one runner: what a job runs is what bench, Table 2 and the tests run."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from icefarm import params
from icefarm.bench.timings import stage_timings
from icefarm.job import STEPS, JobInputs, Stage, run_graph, run_stages, step_keys
from icefarm.job.pipeline import JobSpec, run_job
from icefarm.mesh import prepare

SMALL = {"water.rays": 1500, "drips.count": 6, "storm.max_icicles": 6, "glaze.mode": "none",
         "surface.voxel_size": 0.003}


def _bowl(tmp_path):
    path = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=3).export(path)
    return path


def test_a_job_and_the_bare_chain_give_the_same_stages(tmp_path):
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    run_job(JobSpec("ball", str(path), 0.3, p, seed=4), tmp_path / "job", until=Stage.TRAJECTORIES)
    bare = run_stages(prepare(str(path), 0.3, p.water.gravity), p, 4, until=Stage.TRAJECTORIES)
    job = json.loads((tmp_path / "job" / "drips.json").read_text())["drip_points"]
    assert len(job) == len(bare.drips.positions) > 0
    np.testing.assert_allclose([d["position"] for d in job], bare.drips.positions, atol=1e-9)
    assert bare.ice is None and bare.trajectories.n_branches >= len(job)


def test_steps_come_in_order_and_stop_where_asked(tmp_path):
    p = params.resolve(SMALL)
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p.water.gravity)
    seen, files = [], []
    result = run_graph(JobInputs(prepared, p), until=Stage.DRIPS,
                       step=lambda s, key, work: seen.append(s.name) or work(),
                       on_step=lambda s, r: files.append((s.name, r.drips is not None)))
    assert seen == ["refine", "water", "drips"]  # a physical storm refines its flow surface
    assert files == [("flow", False), ("refine", False), ("water", False), ("drips", True)]
    assert result.trajectories is None and result.flow is result.mesh


def test_a_proxy_run_hangs_its_icicles_from_the_object(tmp_path):
    p = params.resolve({**SMALL, "proxy.mode": "always", "proxy.face_budget": 4000})  # a coarse wrap, for speed
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p.water.gravity)
    seen = []
    result = run_stages(prepared, p, 0, until=Stage.TRAJECTORIES,
                        step=lambda s, key, work: seen.append(s.name) or work())
    assert seen[:3] == ["proxy", "refine", "water"] and result.flow is not result.mesh and result.proxy_reason
    distance = np.abs(trimesh.proximity.signed_distance(result.mesh, result.drips.positions))
    assert distance.max() < 1e-6


def test_the_benchmark_times_the_jobs_chain(tmp_path):
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    runs = stage_timings(str(path), 0.3, p, repeat=1, surface=True)
    bare = run_stages(prepare(str(path), 0.3, p.water.gravity), p, 0)
    assert set(runs.seconds) == {"refine", "water", "drips", "trajectories", "surface"}
    assert runs.icicles == len(bare.drips.positions) and runs.ice_faces == len(bare.ice.faces)


def test_an_unknown_override_is_refused(tmp_path):
    p = params.resolve(SMALL)
    prepared = prepare(str(_bowl(tmp_path)), 0.3, p.water.gravity)
    with pytest.raises(ValueError, match="surface"):
        run_stages(prepared, p, 0, overrides={"surface": "ice.ply"})


def _job(tmp_path, path, name, p, **extra):
    outcome = run_job(JobSpec("ball", str(path), 0.3, p, seed=4, **extra), tmp_path / name, until=Stage.TRAJECTORIES)
    assert outcome.status == "done", outcome.error
    return tmp_path / name


def test_edited_drips_and_painted_water_replace_what_the_stages_found(tmp_path):
    """A manifest's overrides: an artist's drips.json hangs exactly its icicles; a painted
    water.ply replaces the water coefficients (the walks stay) and moves the drips."""
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    first = _job(tmp_path, path, "first", p)
    drips = json.loads((first / "drips.json").read_text())
    kept = drips["drip_points"][:2]
    (tmp_path / "edited.json").write_text(json.dumps({**drips, "drip_points": kept}))
    edited = _job(tmp_path, path, "edited", p, overrides=(("drips", str(tmp_path / "edited.json")),))
    again = json.loads((edited / "drips.json").read_text())["drip_points"]
    np.testing.assert_allclose([d["position"] for d in again], [d["position"] for d in kept])
    assert len(json.loads((edited / "trajectories.json").read_text())["icicles"]) == 2

    water = trimesh.load(first / "water.ply", process=False)
    data = water.metadata["_ply_raw"]["vertex"]["data"]
    heights = np.asarray(water.vertices)[:, 1]
    painted = np.where(heights < np.percentile(heights, 30), 0.0, np.asarray(data["water"]))  # dry below
    out = trimesh.Trimesh(water.vertices, water.faces, process=False)
    out.vertex_attributes["supply"] = np.asarray(data["supply"]).astype(np.uint8)
    out.vertex_attributes["water"] = painted.astype(np.float32)
    out.export(tmp_path / "painted.ply")
    repainted = _job(tmp_path, path, "painted", p, overrides=(("water", str(tmp_path / "painted.ply")),))
    back = trimesh.load(repainted / "water.ply", process=False).metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_allclose(np.asarray(back["water"]), painted, atol=1e-6)
    assert json.loads((repainted / "drips.json").read_text())["drip_points"] != drips["drip_points"]


def test_edited_trajectories_are_the_icicles_built(tmp_path):
    path = _bowl(tmp_path)
    p = params.resolve(SMALL)
    first = _job(tmp_path, path, "first", p)
    traj = json.loads((first / "trajectories.json").read_text())
    traj["icicles"] = traj["icicles"][:1]
    (tmp_path / "one.json").write_text(json.dumps(traj))
    one = _job(tmp_path, path, "one", p, overrides=(("trajectories", str(tmp_path / "one.json")),))
    assert len(json.loads((one / "trajectories.json").read_text())["icicles"]) == 1


def test_a_rain_source_wets_only_what_lies_under_it(tmp_path):
    """water.source: a plate over one half of the ball rains on that half alone."""
    path = _bowl(tmp_path)
    plate = trimesh.creation.box(extents=(1.0, 0.02, 2.0))
    plate.apply_translation((0.5, 3.0, 0.0))  # over x > 0, in the mesh file's units (radius 1)
    plate.export(tmp_path / "rain.ply")
    p = params.resolve({**SMALL, "water.source": "rain.ply"})
    job = _job(tmp_path, path, "half", p)
    water = trimesh.load(job / "water.ply", process=False)
    supply = np.asarray(water.metadata["_ply_raw"]["vertex"]["data"]["supply"]).astype(bool)
    x = np.asarray(water.vertices)[:, 0]
    assert supply.any() and x[supply].min() > -0.02


def _keys(p, **job):
    prepared = prepare(trimesh.creation.icosphere(subdivisions=2), 0.3, p.water.gravity)
    return step_keys(JobInputs(prepared, p, **job))


def _downstream(names):
    """The steps that read one of ``names``, directly or not, and ``names`` themselves."""
    out = set(names)
    for s in STEPS:
        if out & set(s.after):
            out.add(s.name)
    return out


@pytest.mark.parametrize("group", ["storm", "water", "drips", "trajectories", "surface", "glaze", "proxy"])
def test_a_parameter_added_to_a_group_changes_the_keys_of_the_steps_that_declare_it(group):
    """Cache keys come from the declarations: a new field in a group changes the key of
    each step that declares the whole group and of the steps downstream, and no other."""
    import dataclasses

    p = params.resolve({"ground_ice.mode": "mounds", "proxy.mode": "always"})
    value = getattr(p, group)
    wider = dataclasses.make_dataclass("Wider", [(f.name, f.type) for f in dataclasses.fields(value)]
                                       + [("added", float)], frozen=True)
    q = dataclasses.replace(p, **{group: wider(**dataclasses.asdict(value), added=1.0)})
    declaring = {s.name for s in STEPS if group in s.reads or group in s.physical_reads}
    before, after = _keys(p), _keys(q)
    changed = {name for name in before if before[name] != after[name]}
    assert declaring and changed == _downstream(declaring)


def test_a_single_parameter_changes_only_the_steps_that_read_it():
    p = params.resolve({})
    before = _keys(p)
    after = _keys(p.updated({"glaze.lifetime": p.glaze.lifetime * 2}))
    changed = {name for name in before if before[name] != after[name]}
    running = {name for name, key in before.items() if key is not None}
    assert changed == _downstream({"water", "surface"}) & running  # water reads glaze.lifetime, surface all glaze
    assert _keys(p, seed=1)["flow"] == before["flow"] and _keys(p, seed=1)["water"] != before["water"]


def test_no_function_switches_on_a_step_name():
    """The runner and the pipeline act on declarations: no ``name == "water"`` or
    ``name in ("water", ...)`` anywhere in the package."""
    import ast
    from pathlib import Path

    import icefarm
    from icefarm.job import STEP_NAMES

    names = {*STEP_NAMES, "prepare", "render", "usd", "ice_layer", "growth"}  # the graph's and the pipeline's

    def is_name(node):
        return isinstance(node, ast.Constant) and node.value in names

    def names_a_step(node):  # a variable that holds a step's or stage's name (not a parameter's choice)
        text = ast.unparse(node)
        return isinstance(node, (ast.Name, ast.Attribute)) and any(w in text for w in ("stage", "step", "name"))

    found = []
    for path in Path(icefarm.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            sides = [node.left, *node.comparators]
            if not any(map(names_a_step, sides)):
                continue
            equal = any(isinstance(op, (ast.Eq, ast.NotEq)) for op in node.ops) and any(map(is_name, sides))
            member = any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops) and any(
                isinstance(side, (ast.Tuple, ast.List, ast.Set)) and any(map(is_name, side.elts)) for side in sides)
            if equal or member:
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert not found, "\n".join(found)


def test_timings_json_holds_every_figure_the_steps_declare(tmp_path):
    """run_job writes what each step that ran declares (`Step.figures`) through one record,
    `JobStats`, which reads back as it was written."""
    from icefarm.job import JobStats

    path = _bowl(tmp_path)
    p = params.resolve({**SMALL, "ground_ice.mode": "mounds"})
    outcome = run_job(JobSpec("ball", str(path), 0.3, p, seed=4), tmp_path / "job", until=Stage.SURFACE)
    assert outcome.status == "done", outcome.error
    stats = JobStats.read(tmp_path / "job" / "timings.json")
    prepared = prepare(str(path), 0.3, p.water.gravity)
    inputs = JobInputs(prepared, p, 4)
    ran = [s for s in STEPS if s.figures is not None and step_keys(inputs)[s.name] is not None]
    assert {s.name for s in ran} >= {"water", "drips", "trajectories", "ground_ice", "surface", "measure"}
    results = run_graph(inputs, measuring=True)
    for s in ran:
        assert set(s.figures(inputs, results)) <= set(stats.figures), s.name
    assert set(stats.seconds) >= {s.name for s in ran} and not stats.render_pending
    assert JobStats.from_json(stats.as_json()) == stats
