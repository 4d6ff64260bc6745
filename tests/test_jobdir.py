"""One reading of a job folder's records, shared by the sweep, report, sheets and CLI."""

from icefarm.jobdir import error_line, total_seconds


def test_the_line_that_stands_for_a_failure_names_the_exception():
    assert error_line("\n  ValueError: bad mesh\n  at line 3\n") == "ValueError: bad mesh"
    assert error_line(None) == "-" and error_line("  \n", "unknown error") == "unknown error"


def test_a_jobs_total_seconds_sums_its_steps_and_nothing_else():
    assert total_seconds({"water": 0.5, "render": 2.0, "cached": True, "note": "x"}) == 2.5
    assert total_seconds({}) is None and total_seconds(None) is None and total_seconds([1, 2]) is None


def test_a_failure_between_steps_is_not_blamed_on_the_step_before(tmp_path, monkeypatch):
    """The pipeline records the gap between steps (``after <step>``), and names what failed
    outside them: a bad render config (a manifest edited since) fails the job before its
    stages compute anything, as ``render config``, not as the stage before or after it."""
    from icefarm import params
    from icefarm.job.pipeline import JobSpec, run_job
    from icefarm.jobdir import stage_phrase

    assert stage_phrase("surface") == "in stage surface"
    assert stage_phrase("after measure") == "after stage measure"
    # the physical storm's rims take max_icicles, not drips.count; a coarse flow mesh: quick
    quick = {"storm.max_icicles": 2, "storm.flow_edge": 0.05, "glaze.mode": "none", "surface.voxel_size": 0.003}
    spec = JobSpec("roof", "generator:roof", 0.3, params.resolve(quick), seed=0, render="no-such-config")
    outcome = run_job(spec, tmp_path / "job")
    assert outcome.status == "failed" and outcome.failed_stage == "render config"
    assert "no-such-config" in outcome.error and outcome.seconds == {}
    assert stage_phrase(outcome.failed_stage) == "in stage render config"


def test_the_views_read_back_as_written(tmp_path):
    from icefarm.jobdir import VIEWS, read_views, view_stem, write_views

    write_views(tmp_path, [("three_quarter", "all", 3.5), ("ice", "ice", None)])
    views = read_views(tmp_path)
    assert [v["stem"] for v in views] == [view_stem(0), view_stem(1)] == ["render", "render_view1"]
    assert views[1] == {"index": 1, "name": "ice", "frame": "ice", "stem": "render_view1", "icicle_px": None}
    (tmp_path / VIEWS).write_text("{not json")
    assert read_views(tmp_path) == [] and read_views(tmp_path / "nowhere") == []


def test_one_scan_of_a_sweep_folder_for_every_reader(tmp_path):
    """jobs.csv's order first, the rest by path; hidden job folders left out; a job folder or a
    folder above job folders scanned too."""
    from icefarm.jobdir import DONE, PARAMS, scan_sweep

    for obj, job in (("a", "j1"), ("a", "j2"), ("b", "j3"), ("a", ".tmp")):
        (tmp_path / "jobs" / obj / job).mkdir(parents=True)
    (tmp_path / "jobs.csv").write_text("job_id,object,drips.count,status\nj3,b,2,done\nj2,a,3,done\n")
    found = scan_sweep(tmp_path)
    assert found.is_sweep and [p.name for p in found.job_dirs] == ["j3", "j2", "j1"]
    assert found.swept == ("drips.count",) and [r["job_id"] for r in found.rows] == ["j3", "j2"]
    assert found.manifest() == {}
    job = tmp_path / "jobs" / "a" / "j1"
    (job / DONE).write_text("{}")
    assert scan_sweep(job).job_dirs == (job,) and not scan_sweep(job).is_sweep
    (tmp_path / "jobs" / "b" / "j3" / PARAMS).write_text("{}")
    assert [p.name for p in scan_sweep(tmp_path / "jobs").job_dirs] == ["j1", "j3"]


def test_sky_and_growth_file_names():
    from icefarm.jobdir import growth_clip, growth_frame, growth_ice, sky_name

    assert sky_name("procedural", 120, 45.5) == "sky_az120_el45.5.exr"
    assert sky_name("/skies/Studio.HDR", 0, 0) == "sky_Studio.hdr"
    assert (growth_ice(3), growth_frame(3), growth_clip(12)) == ("ice_0003.ply", "frame_0003.png", "ice_0012.usdc")
