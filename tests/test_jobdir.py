"""One reading of a job folder's records, shared by the sweep, report, sheets and CLI."""

from icefarm.jobdir import error_line, total_seconds


def test_the_line_that_stands_for_a_failure_names_the_exception():
    assert error_line("\n  ValueError: bad mesh\n  at line 3\n") == "ValueError: bad mesh"
    assert error_line(None) == "-" and error_line("  \n", "unknown error") == "unknown error"


def test_a_jobs_total_seconds_sums_its_steps_and_nothing_else():
    assert total_seconds({"water": 0.5, "render": 2.0, "cached": True, "note": "x"}) == 2.5
    assert total_seconds({}) is None and total_seconds(None) is None and total_seconds([1, 2]) is None


def test_a_failure_between_steps_is_not_blamed_on_the_step_before(tmp_path, monkeypatch):
    """A bad render config found after stage 4 (a manifest edited since) used to read
    "failed in stage measure"; the pipeline now records the gap between steps."""
    from icefarm import params
    from icefarm.jobdir import stage_phrase
    from icefarm.pipeline import JobSpec, run_job

    assert stage_phrase("surface") == "in stage surface"
    assert stage_phrase("after measure") == "after stage measure"
    quick = {"drips.count": 2, "glaze.mode": "none", "surface.voxel_size": 0.003}
    spec = JobSpec("roof", "generator:roof", 0.3, params.resolve(quick), seed=0, render="no-such-config")
    outcome = run_job(spec, tmp_path / "job")
    assert outcome.status == "failed" and outcome.failed_stage == "after measure"
    assert "no-such-config" in outcome.error
