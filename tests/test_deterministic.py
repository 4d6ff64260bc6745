"""No behaviour change goes unseen: a job, or a tiny sweep, run twice from scratch
writes the same bytes wherever its output is deterministic today.

Left out, and why: ``timings.json``, ``done.json`` (it repeats the timings), ``jobs.csv``,
``report.md``/``report.csv``, the gallery and the contact sheets: each prints every job's
seconds (a sheet's label strip too: about 200 pixels of the PNG and EXR change from run to
run), so none is byte-identical today. Renders are compared to the rounding of Mitsuba's
film: the JIT variants add the samples' (filtered) weights into the pixels with atomic adds
from several threads, whose order changes the last bit now and then (a clean-clone CI run:
one half-float in render.exr's 48 x 36 x 3, one step in its last bit). Their headers must
match but for when they were written (``DateTime``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from icefarm import params
from icefarm.jobdir import (
    DRIPS,
    ICE,
    ICE_INC,
    MANIFEST,
    OBJECT,
    OBJECT_INC,
    PARAMS,
    RENDER_EXR,
    RENDER_PNG,
    SCENE_POV,
    SCENE_SPEC,
    SCENE_XML,
    TRAJECTORIES,
    VIEWS,
    WATER,
    scan_sweep,
)
from icefarm.params import flatten

STAGES = (PARAMS, WATER, DRIPS, TRAJECTORIES, ICE)
SCENE = (SCENE_SPEC, SCENE_XML, SCENE_POV, OBJECT, OBJECT_INC, ICE_INC, VIEWS)


def quick(kit) -> dict:
    """The quick jobs' defaults with coarse voxels and four icicles: a surface in a fraction of a second."""
    return {**kit.fast, "storm": {"max_icicles": 4}, "surface": {"voxel_size": 0.004}, "glaze": {"voxel_size": 0.016}}


def assert_same_bytes(a, b, names):
    """Each of ``names`` is in folders ``a`` and ``b`` with the same bytes."""
    for name in names:
        assert (a / name).is_file(), f"{a / name} was not written"
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs between two runs"


def assert_same_render(a, b):
    """Two renders (EXR or PNG) of one scene: the same header but for when they were written
    (``DateTime``), and the same pixels but for the film's rounding: every value within 2^-9
    of the larger (half a float16 step more than one) or one 8-bit level, and at most one in a
    hundred off at all. A change to the scene moves far more of them, far further."""
    import OpenImageIO as oiio

    images = [oiio.ImageInput.open(str(p)) for p in (a, b)]
    try:
        specs = [i.spec() for i in images]
        headers = [{x.name: str(x.value) for x in s.extra_attribs if x.name != "DateTime"} for s in specs]
        assert headers[0] == headers[1] and specs[0].format == specs[1].format
        assert (specs[0].width, specs[0].height, specs[0].nchannels) == (specs[1].width, specs[1].height,
                                                                         specs[1].nchannels)
        pixels = [np.asarray(i.read_image("float"), dtype=np.float64) for i in images]
    finally:
        for i in images:
            i.close()
    step = 1.0 / 255 if specs[0].format == oiio.UINT8 else 0.0
    off = np.abs(pixels[0] - pixels[1])
    tol = np.maximum(2.0**-9 * np.maximum(np.abs(pixels[0]), np.abs(pixels[1])), step) + 1e-12
    assert np.all(off <= tol), f"{a.name}: its pixels differ between two runs by up to {off.max():.3g}"
    assert np.mean(off > 0) <= 0.01, f"{a.name}: {np.mean(off > 0):.1%} of its values differ between two runs"


def test_a_job_run_twice_writes_the_same_stage_files(tmp_path, ball, sweep_kit):
    from icefarm.job.pipeline import JobSpec, Stage, run_job

    spec = JobSpec("ball", str(ball), 0.3, params.resolve(quick(sweep_kit)), seed=5)
    for run in ("a", "b"):
        assert run_job(spec, tmp_path / run, until=Stage.SURFACE).status == "done"
    assert_same_bytes(tmp_path / "a", tmp_path / "b", STAGES)


@pytest.fixture(scope="module")
def twice(tmp_path_factory, sweep_kit):
    """A two-job sweep with a tiny render, run from scratch into two folders on two worker
    processes (the second job takes water and drips from the stage cache): ``runs``, per run
    its job folders in job order, and ``mesh``."""
    from icefarm.farm.sweep import SweepOptions, run_sweep

    root = tmp_path_factory.mktemp("twice")
    ball, render = sweep_kit.ball(root), sweep_kit.tiny_render(root)
    manifest = {"name": "t", "seed": 1, "render": render.name, "defaults": quick(sweep_kit),
                "objects": [{"id": "ball", "mesh": ball.name, "size_m": 0.3}],
                "sweep": {"method": "grid", "parameters": {"trajectories.curve_angle": {"values": [1, 5]}}}}
    (root / "m.yaml").write_text(yaml.safe_dump(manifest))
    runs = []
    for run in ("a", "b"):
        summary = run_sweep(root / "m.yaml", root / run, SweepOptions(workers=2))
        assert summary.ok and summary.done == 2
        runs.append(scan_sweep(summary.sweep_dir).job_dirs)
    return SimpleNamespace(runs=runs, mesh=ball, render=render)


@pytest.mark.slow  # starts two worker processes per sweep and renders
def test_a_sweep_run_twice_writes_the_same_stages_scenes_and_renders(twice):
    first, second = twice.runs
    assert [d.name for d in first] == [d.name for d in second] and len(first) == 2
    for a, b in zip(first, second):
        assert_same_bytes(a, b, STAGES + SCENE)
        for render in (RENDER_PNG, RENDER_EXR):
            assert_same_render(a / render, b / render)
    sweep_a, sweep_b = (d[0].parents[2] for d in twice.runs)
    assert_same_bytes(sweep_a, sweep_b, (MANIFEST,))


@pytest.mark.slow  # compares with the sweep's, whose workers are processes (this job runs in this one)
def test_icefarm_run_builds_the_ice_a_sweep_worker_built(twice, tmp_path, sweep_kit):
    from click.testing import CliRunner

    from icefarm.cli import main

    job = twice.runs[0][0]
    entry = next(j for j in yaml.safe_load((job.parents[2] / MANIFEST).read_text())["jobs"] if j["id"] == job.name)
    sets = [f"--set={k}={v}" for k, v in {**flatten(quick(sweep_kit)), **entry["values"]}.items()]
    # meshed for the sweep's render config, as the worker meshed it
    result = CliRunner().invoke(main, ["run", str(twice.mesh), "--size-m", "0.3", "--seed",
                                       str(entry["seed"]), "--until", "surface", "--render", str(twice.render),
                                       "-o", str(tmp_path / "direct"), *sets])
    assert result.exit_code == 0, result.output
    assert_same_bytes(job, tmp_path / "direct", (ICE,))
