"""The ice is meshed for how the job will be seen: a preview meshes for its own pixels."""

import json

import pytest

from icefarm import params
from icefarm.export import meshed_coarser
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.scene.config import load_render_config
from icefarm.scene.focus import MIN_ZOOM
from icefarm.stages.surface.detail import ICE_ZOOM, VIEW_PX, VIEW_PX_HIGH, meshing_view, view_surface


def test_a_view_showing_less_than_lookdev_scales_the_budgets_and_lookdev_keeps_them():
    s = params.resolve({}).surface
    # preview: 320 x 240, the whole object only (an ice view zooms ICE_ZOOM times or more)
    share = 320 * 240 / (VIEW_PX * VIEW_PX_HIGH) / ICE_ZOOM ** 2
    small = view_surface(s, meshing_view((320, 240)))
    assert small.face_budget == round(s.face_budget * share)
    assert small.error_px == pytest.approx(s.error_px / share ** 0.5)
    # the same size with an ice view shows the mesh ICE_ZOOM times larger
    close = view_surface(s, meshing_view((320, 240), ice_view=True))
    assert close.face_budget == round(s.face_budget * 320 * 240 / (VIEW_PX * VIEW_PX_HIGH))
    # lookdev, larger views (final's full HD, no ice view) and no render keep the budgets as set
    for resolution, ice_view in (((480, 360), True), ((1920, 1080), False), ((1920, 1080), True), (None, False)):
        assert view_surface(s, meshing_view(resolution, ice_view)) is s
    assert ICE_ZOOM == MIN_ZOOM  # the scene's ice views zoom at least that much
    off = params.resolve({"surface.face_budget": 0, "surface.error_px": 0}).surface
    off_small = view_surface(off, meshing_view((320, 240)))
    assert off_small.face_budget == 0 and off_small.error_px == 0


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
        assert t["mesh_ice_view"] is (name == "none")  # no render: lookdev's, ice view included
        # in the pixels of its own view: a preview shows it as large as lookdev's ice view does
        assert t["mesh_error_px"] == pytest.approx(p.surface.error_px * (ICE_ZOOM if name == "preview" else 1))
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
