"""Renders: Mitsuba in process and on its command line, POV-Ray, EXR and PNG, sample passes,
deferred POV-Ray files, and what the ice does to the picture."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from icefarm.errors import InputError
from icefarm.scene import povray as pov
from icefarm.scene.config import render_config_to_dict
from icefarm.scene.images import read_image
from icefarm.scene.render import render_job
from icefarm.scene.variants import find_libllvm
from icefarm.scene.write import JobScene, write_scenes

ROOT = Path(__file__).resolve().parents[1]
MITSUBA_CLI = Path(sys.executable).parent / "mitsuba"


@pytest.mark.slow
def test_mitsuba_command_line_renders_the_scene(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    """scene.xml loads in a separate process with the wheel's `mitsuba` renderer."""
    if not MITSUBA_CLI.is_file():
        pytest.skip(f"no mitsuba command beside {sys.executable}")
    box, ice = box_with_icicles()
    write_scenes(tmp_path, JobScene(box, ice), tiny_config(views=["three_quarter", "front"]))
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": str(find_libllvm() or tmp_path / "none.so")}
    for sensor in ("0", "1"):
        out = subprocess.run([str(MITSUBA_CLI), "-m", "scalar_rgb", "-s", sensor,
                              "-D", "spp=4", "-D", "resx=40", "-D", "resy=30",
                              "-o", f"cli{sensor}.exr", "scene.xml"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
        pixels = read_image(tmp_path / f"cli{sensor}.exr")
        assert pixels.shape[:2] == (30, 40)
        assert_not_blank(pixels)


@pytest.mark.slow
def test_povray_renders_the_scene(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    if shutil.which("povray") is None:
        pytest.skip("povray is not installed (apt-get install povray)")
    box, ice = box_with_icicles()
    config = tiny_config(renderer="povray", resolution=[40, 30])
    write_scenes(tmp_path, JobScene(box, ice), config)
    result = render_job(tmp_path, config)
    assert result.variant == "" and result.povray_seconds > 0 and result.seconds == 0
    assert [p.name for p in result.files[:2]] == ["render.exr", "render.png"]
    pixels = read_image(tmp_path / "render_povray.png")
    assert pixels.shape[:2] == (30, 40)
    assert_not_blank(pixels)
    assert_not_blank(read_image(tmp_path / "render.exr"))


def test_povray_missing_is_a_clear_error(tmp_path, monkeypatch, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config(renderer="both")
    write_scenes(tmp_path, JobScene(box, ice), config)
    monkeypatch.setattr(pov.shutil, "which", lambda name: None)
    with pytest.raises(InputError, match="apt-get install povray"):
        render_job(tmp_path, config)
    assert not (tmp_path / "render.png").exists()  # refused before any rendering


@pytest.mark.slow  # renders
def test_render_job_writes_linear_exr_and_srgb_png(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    box, ice = box_with_icicles()
    config = tiny_config(views=["three_quarter", "below"])
    files = write_scenes(tmp_path, JobScene(box, ice), config)
    result = render_job(tmp_path, config, files)
    assert result.variant in ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
    assert result.integrator == ("volpath" if result.variant == "scalar_rgb" else "icepath")
    assert result.seconds > 0 and result.scene_seconds >= files.seconds
    assert [p.name for p in result.files] == ["render.exr", "render.png",
                                              "render_view1.exr", "render_view1.png"]
    linear, display = read_image(tmp_path / "render.exr"), read_image(tmp_path / "render.png")
    assert linear.shape == display.shape == (36, 48, 3)
    assert_not_blank(display)
    # The PNG is the sRGB encoding of the EXR: mid-tones are lifted, never darkened.
    mid = (linear > 0.01) & (linear < 0.8)
    assert (display[mid] >= linear[mid] - 0.02).all() and display[mid].mean() > linear[mid].mean()


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs CPU affinity (Linux)")
def test_a_process_pinned_to_one_core_renders(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    """Mitsuba reads EXRs (the sky) with Dr.Jit's pool, which waited forever at one thread."""
    box, ice = box_with_icicles()
    config = tiny_config()
    write_scenes(tmp_path, JobScene(box, ice), config)
    code = ("import os, sys; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
            "from icefarm.scene.config import render_config_from_dict; "
            "from icefarm.scene.render import render_job; "
            f"config = render_config_from_dict({render_config_to_dict(config)!r}, name={config.name!r}); "
            "print(render_job(sys.argv[1], config).variant)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True,
                         timeout=180, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    assert_not_blank(read_image(tmp_path / "render.png"))


@pytest.mark.slow  # renders
def test_ice_changes_the_picture_where_it_projects(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config(resolution=[80, 60], spp=8, denoise="none")
    points = np.vstack([box.vertices, ice.vertices])  # same camera for both pictures
    with_ice = write_scenes(tmp_path / "ice", JobScene(box, ice, frame_points=points), config)
    write_scenes(tmp_path / "bare", JobScene(box, None, frame_points=points), config)
    render_job(tmp_path / "ice", config)
    assert render_job(tmp_path / "bare", config).integrator == "path"  # nothing for icepath to do
    a = read_image(tmp_path / "ice" / "render.exr")
    b = read_image(tmp_path / "bare" / "render.exr")
    diff = np.abs(a - b).mean(axis=2)
    # Pixels the icicles cover: project dense surface samples of the ice.
    samples, _ = trimesh.sample.sample_surface(ice, 4000, seed=1)
    xy = with_ice.cameras[0].project(samples, 80, 60).astype(int)
    mask = np.zeros((60, 80), bool)
    mask[np.clip(xy[:, 1], 0, 59), np.clip(xy[:, 0], 0, 79)] = True
    assert mask.sum() > 20
    assert diff[mask].mean() > 0.05
    assert diff[mask].mean() > 3 * diff[~mask].mean()


@pytest.mark.slow  # renders
def test_deferred_povray_files_are_whole_when_the_render_returns(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config()
    sync = write_scenes(tmp_path / "sync", JobScene(box, ice), config)
    files = write_scenes(tmp_path / "bg", JobScene(box, ice), config, defer_povray=True)
    assert sync.povray_writer is None and files.povray_writer is not None
    assert not (tmp_path / "bg" / "scene.pov").exists() and (tmp_path / "bg" / "scene.xml").is_file()
    result = render_job(tmp_path / "bg", config, files)
    for name in ("scene.pov", "object.inc", "ice.inc", "scene.xml"):
        assert (tmp_path / "bg" / name).read_bytes() == (tmp_path / "sync" / name).read_bytes(), name
    assert result.scene_seconds == pytest.approx(result.write_seconds + result.load_seconds + result.wait_seconds)
    assert result.write_seconds == files.seconds and result.load_seconds > 0
    assert result.povray_write_cpu_seconds > 0
    assert render_job(tmp_path / "sync", config).povray_write_cpu_seconds == 0  # nothing deferred


def test_a_failed_render_still_leaves_whole_povray_files(tmp_path, monkeypatch, box_with_icicles, tiny_config):
    import icefarm.scene.render as render_module

    box, ice = box_with_icicles()
    config = tiny_config()

    def broken(*args, **kwargs):
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(render_module, "render_mitsuba", broken)
    files = write_scenes(tmp_path, JobScene(box, ice), config, defer_povray=True)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        render_job(tmp_path, config, files)
    assert "Ice_Mesh" in (tmp_path / "scene.pov").read_text()  # written and finished before the error left
    assert (tmp_path / "ice.inc").read_bytes().endswith(b"}\n")


@pytest.mark.parametrize("pixels, spp, budget, expected", [
    (480 * 360, 96, 1 << 25, [96]),        # lookdev: one pass
    (100, 10, 250, [3, 3, 2, 2]),          # uneven split, all samples kept
    (10, 3, 1, [1, 1, 1]),                 # never a pass without samples
])
def test_sample_passes_split_spp_without_losing_any(pixels, spp, budget, expected):
    from icefarm.scene.render import sample_passes

    assert sample_passes(pixels, spp, budget) == expected
    assert sum(sample_passes(1920 * 1080, 512)) == 512 and len(sample_passes(1920 * 1080, 512)) > 1
    with pytest.raises(ValueError):
        sample_passes(0, 4)


@pytest.mark.slow  # renders
def test_render_in_passes_matches_one_pass(tmp_path, monkeypatch, box_with_icicles, tiny_config, assert_not_blank):
    """Passes with their own seeds average to the same picture as one pass (up to noise)."""
    import icefarm.scene.render as render_module

    box, ice = box_with_icicles()
    config = tiny_config(spp=32)
    write_scenes(tmp_path / "one", JobScene(box, ice), config)
    write_scenes(tmp_path / "many", JobScene(box, ice), config)
    render_job(tmp_path / "one", config)
    monkeypatch.setattr(render_module, "PASS_SAMPLES", 48 * 36 * 8)  # four passes of 8 spp
    render_job(tmp_path / "many", config, progress=True)
    a = read_image(tmp_path / "one" / "render.exr")
    b = read_image(tmp_path / "many" / "render.exr")
    assert_not_blank(b)
    assert abs(a.mean() - b.mean()) < 0.03 * a.mean()
    assert not np.array_equal(a, b)  # the passes really sampled anew


@pytest.mark.slow  # a real Mitsuba render
def test_rough_ice_renders_finite_and_differs_from_clear_ice(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    box, ice = box_with_icicles()
    points = np.vstack([box.vertices, ice.vertices])
    images = {}
    for name, roughness in (("clear", 0.0), ("frosted", 0.3)):
        config = tiny_config(resolution=[64, 48], spp=16, ice={"roughness": roughness})
        files = write_scenes(tmp_path / name, JobScene(box, ice, frame_points=points), config)
        render_job(tmp_path / name, config)
        images[name] = read_image(tmp_path / name / "render.exr")
        assert_not_blank(images[name])
    samples, _ = trimesh.sample.sample_surface(ice, 4000, seed=1)
    xy = files.cameras[0].project(samples, 64, 48).astype(int)
    on_ice = np.zeros((48, 64), bool)
    on_ice[np.clip(xy[:, 1], 0, 47), np.clip(xy[:, 0], 0, 63)] = True
    diff = np.abs(images["clear"] - images["frosted"]).mean(axis=2)
    assert diff[on_ice].mean() > 2 * diff[~on_ice].mean()  # the ice changed, not just the noise


def _ice_mask(camera, ice, width, height):
    samples, _ = trimesh.sample.sample_surface(ice, 6000, seed=1)
    xy = camera.project(samples, width, height).astype(int)
    mask = np.zeros((height, width), bool)
    mask[np.clip(xy[:, 1], 0, height - 1), np.clip(xy[:, 0], 0, width - 1)] = True
    return mask


@pytest.mark.slow  # renders
def test_impurity_clouds_the_ice_and_impurity_zero_is_clear(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    from icefarm.scene.variants import pick_variant

    if pick_variant("auto") == "scalar_rgb":
        pytest.skip("icepath (a JIT variant) renders the medium's scattering cheaply; volpath is too noisy here")
    box, ice = box_with_icicles()
    points = np.vstack([box.vertices, ice.vertices])  # same camera for every picture
    look = {"resolution": [80, 60], "spp": 32,
            "environment": {"sun_elevation": 10, "sun_azimuth": 35}}  # a low sun lights the icicles
    config = tiny_config(**look, ice={"scattering": 60.0})  # cloudier than the default: a clear signal
    images = {}
    for name, impurity, cfg in (("pure", 0.0, config), ("tap", 0.6, config),
                                ("unscattering", 0.6, tiny_config(**look, ice={"scattering": 0.0}))):
        files = write_scenes(tmp_path / name, JobScene(box, ice, frame_points=points, impurity=impurity), cfg)
        render_job(tmp_path / name, cfg)
        images[name] = read_image(tmp_path / name / "render.exr")
        assert_not_blank(images[name])
    # Impurity 0 is the absorbing ice without scattering: the same scene, the same picture
    # (up to the order in which the film's threads add samples).
    assert (tmp_path / "pure" / "scene.xml").read_text() == (tmp_path / "unscattering" / "scene.xml").read_text()
    np.testing.assert_allclose(images["pure"], images["unscattering"], atol=2e-3)
    on_ice = _ice_mask(files.cameras[0], ice, 80, 60)
    diff = np.abs(images["tap"] - images["pure"]).mean(axis=2)
    assert diff[on_ice].mean() > 3 * diff[~on_ice].mean()  # the ice changed, not the rest
    tap, pure = images["tap"][on_ice].mean(axis=0), images["pure"][on_ice].mean(axis=0)
    assert tap.mean() > 1.15 * pure.mean()  # a brighter, whiter core
    assert tap.min() / tap.max() > pure.min() / pure.max()
