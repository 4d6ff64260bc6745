"""The ice is meshed for how the job will be seen: a preview meshes for its own pixels."""

import json

import pytest

from icefarm import params
from icefarm.export import meshed_coarser
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.scene.config import load_render_config
from icefarm.stages.surface.detail import VIEW_PX, VIEW_PX_HIGH, view_surface


def test_a_smaller_view_scales_the_budgets_and_lookdev_keeps_them():
    s = params.resolve({}).surface
    small = view_surface(s, (320, 240))
    assert small.face_budget == round(s.face_budget * 320 * 240 / (VIEW_PX * VIEW_PX_HIGH))
    assert small.error_px == pytest.approx(s.error_px * VIEW_PX / 320)  # the same pixels, of the smaller view
    # lookdev, a larger view, a close-up on the ice and no render keep the budgets as set
    for resolution, close_up in (((480, 360), False), ((1920, 1080), False), ((320, 240), True), (None, False)):
        assert view_surface(s, resolution, close_up) is s
    off = params.resolve({"surface.face_budget": 0, "surface.error_px": 0}).surface
    assert view_surface(off, (320, 240)).face_budget == 0 and view_surface(off, (320, 240)).error_px == 0


def test_a_preview_job_meshes_fewer_faces_records_its_view_and_lookdev_says_so(tmp_path, ball, sweep_kit):
    # a budget the ball's glaze and icicles fill: the preview's share of it binds
    values = {**sweep_kit.fast, "storm": {"max_icicles": 4}, "surface": {"voxel_size": 0.002, "face_budget": 40000}}
    p = params.resolve(values)
    faces, views = {}, {}
    for name, render in (("preview", "preview"), ("none", None)):
        outcome = run_job(JobSpec("ball", str(ball), 0.3, p, seed=3, render=render), tmp_path / name,
                          until=Stage.SURFACE)
        assert outcome.status == "done", outcome.error
        t = json.loads((tmp_path / name / "timings.json").read_text())
        faces[name], views[name] = t["ice_faces"], t["mesh_view_px"]
        assert t["mesh_error_px"] == pytest.approx(p.surface.error_px)  # in the pixels of its own view
        # params.yaml keeps the budget as set, whatever the view
        assert f"face_budget: {p.surface.face_budget}" in (tmp_path / name / "params.yaml").read_text()
    assert views == {"preview": [320, 240], "none": [VIEW_PX, VIEW_PX_HIGH]}
    assert faces["preview"] < 0.8 * faces["none"]
    note = meshed_coarser(tmp_path / "preview", load_render_config("lookdev"))
    assert note is not None and "320x240" in note and "--render lookdev" in note
    assert meshed_coarser(tmp_path / "preview", load_render_config("preview")) is None
    assert meshed_coarser(tmp_path / "none", load_render_config("final")) is None


def test_a_deferred_render_finishes_the_job_elsewhere_and_only_once(tmp_path, ball, sweep_kit):
    from icefarm.errors import InputError
    from icefarm.job.pipeline import finish_render
    from icefarm.jobdir import JobState, job_state

    p = params.resolve({**sweep_kit.fast, "storm": {"max_icicles": 4}, "surface": {"voxel_size": 0.004}})
    spec = JobSpec("ball", str(ball), 0.3, p, seed=3, render=str(sweep_kit.tiny_render(tmp_path)))
    job = tmp_path / "job"
    outcome = run_job(spec, job, defer_render=True)
    # the stages' files, no render and nothing that looks done
    assert outcome.status is JobState.PENDING and job_state(job) is JobState.PENDING
    assert (job / "ice.ply").is_file() and not (job / "render.png").exists()
    assert json.loads((job / "timings.json").read_text())["render_pending"] is True
    done = finish_render(spec, job)
    assert done.status is JobState.DONE and (job / "render.png").is_file() and (job / "done.json").is_file()
    timings = json.loads((job / "timings.json").read_text())
    assert {"surface", "measure", "render"} <= set(timings["seconds"]) and "render_pending" not in timings
    # a finished job (or a folder with no job) is refused, and left as it was
    before = (job / "done.json").read_bytes()
    for folder in (job, tmp_path / "nothing"):
        with pytest.raises(InputError, match="no job waiting for its render"):
            finish_render(spec, folder)
    assert (job / "done.json").read_bytes() == before and not (job / "error.json").exists()
    # growth frames render inside stage 4: such a job runs whole
    growing = JobSpec("ball", str(ball), 0.3, p.updated({"growth.frames": 2}), seed=3, render=spec.render)
    from icefarm.job.pipeline import renders_apart

    assert renders_apart(spec) and not renders_apart(growing) and not renders_apart(spec, Stage.SURFACE)
