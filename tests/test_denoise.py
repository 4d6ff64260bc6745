"""Denoised renders: OIDN on few samples, guided by the features icepath writes."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from icefarm.errors import InputError
from icefarm.scene.config import load_render_config, render_config_from_dict
from icefarm.scene.denoise import denoise
from icefarm.scene.images import read_image
from icefarm.scene.render import render_job
from icefarm.scene.write import JobScene, write_scenes


def _stripes(h=64, w=96):
    """A sharp-edged test picture: vertical bars of two greys."""
    x = np.arange(w)[None, :, None] * np.ones((h, 1, 3))
    return np.where((x // 16) % 2 == 0, 0.2, 0.8)


def test_denoise_removes_noise_and_keeps_edges():
    clean = _stripes()
    rng = np.random.default_rng(1)
    noisy = clean * rng.gamma(4.0, 0.25, clean.shape)  # Monte Carlo-like: positive, mean-preserving
    albedo = clean  # what each pixel shows
    normal = np.zeros_like(clean)
    normal[..., 2] = 1.0
    out = denoise(noisy, albedo, normal)
    assert out.shape == clean.shape and out.dtype == np.float32
    assert np.mean((out - clean) ** 2) < np.mean((noisy - clean) ** 2) / 20
    # the bars stay bars: the step between them is still most of its height one pixel over
    row = out[32, :, 0]
    assert row[17] - row[14] > 0.4


def test_denoise_refuses_mismatched_inputs():
    rgb = np.ones((8, 8, 3))
    with pytest.raises(ValueError, match="albedo"):
        denoise(rgb, np.ones((8, 9, 3)))
    with pytest.raises(ValueError, match="only with an albedo"):
        denoise(rgb, None, np.ones((8, 8, 3)))
    with pytest.raises(ValueError, match=r"\(h, w, 3\)"):
        denoise(np.ones((8, 8)))


def test_lookdev_denoises_and_the_key_is_validated():
    assert load_render_config("lookdev").denoise == "oidn"
    assert load_render_config("final").denoise == "none"
    with pytest.raises(InputError, match="denoise"):
        render_config_from_dict({"denoise": "yes"})


@pytest.mark.slow
def test_denoised_render_is_box_filtered_stratified_and_labelled(tmp_path, box_with_icicles, tiny_config):
    import OpenImageIO as oiio

    box, ice = box_with_icicles()
    config = tiny_config(denoise="oidn", spp=4, resolution=[64, 48])
    files = write_scenes(tmp_path, JobScene(box, ice), config)
    sensor = ET.parse(files.xml).getroot().find("sensor")
    assert sensor.find("sampler").get("type") == "multijitter"
    assert sensor.find("film/rfilter").get("type") == "box"
    result = render_job(tmp_path, config, files)
    assert result.integrator == "icepath" and result.denoise_seconds > 0
    assert len(result.view_seconds) == len(config.views) and sum(result.view_seconds) == pytest.approx(result.seconds)
    image = oiio.ImageInput.open(str(tmp_path / "render.exr"))
    note = image.spec().get_string_attribute("icefarm:denoised")
    image.close()
    assert "OIDN" in note and "albedo and normal" in note and "4 spp" in note
    pixels = read_image(tmp_path / "render.exr")
    assert np.isfinite(pixels).all() and pixels.min() >= 0 and pixels.std() > 0.01


@pytest.mark.slow
def test_denoised_render_is_closer_to_many_samples_than_the_noisy_one(tmp_path, box_with_icicles, tiny_config):
    """Same samples, the same scene: denoising brings the image nearer the 256-spp one."""
    box, ice = box_with_icicles()
    size = [96, 72]
    images = {}
    for name, changes in {"ref": dict(spp=256, denoise="none"), "noisy": dict(spp=8, denoise="none"),
                          "denoised": dict(spp=8, denoise="oidn")}.items():
        out = tmp_path / name
        config = tiny_config(resolution=size, **changes)
        render_job(out, config, write_scenes(out, JobScene(box, ice), config))
        images[name] = read_image(out / "render.png")[..., :3]
    error = {k: np.mean((images[k] - images["ref"]) ** 2) for k in ("noisy", "denoised")}
    assert error["denoised"] < error["noisy"] / 2


@pytest.mark.slow
def test_icepath_features_show_what_lies_behind_the_ice(mi):
    """Albedo and normal of the first diffuse surface, through the ice; zero normal on the sky."""
    from icefarm.scene.integrator import FEATURE_CHANNELS, ice_integrator

    grey = 0.5
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40, "to_world": mi.ScalarTransform4f().look_at(
            origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}}},
        "sky": {"type": "constant", "radiance": 0.3},
        "wall": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([1.5, 0, -1]).scale(2),
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [grey] * 3}}},
        "ice": {"type": "sphere", "radius": 0.3, "bsdf": {"type": "dielectric", "int_ior": 1.31}},
    })
    integrator = ice_integrator(mi.variant(), max_depth=8, features=True)
    image = np.asarray(mi.render(scene, spp=64, integrator=integrator))
    assert image.shape == (32, 32, 3 + len(FEATURE_CHANNELS))
    albedo, normal = image[..., 3:6], image[..., 6:9]
    wall = albedo[4:8, 24:28]  # the wall (the right of the frame), seen directly
    assert np.allclose(wall, grey, atol=1e-3)
    assert np.allclose(normal[4:8, 24:28], [0, 0, 1], atol=1e-3)
    centre = albedo[15:17, 15:17]  # the wall through the sphere: dimmed by the ice's Fresnel terms only
    assert 0.6 * grey < centre.mean() < grey
    # the wall's normal, not the sphere's (less a few paths the sphere reflects to the sky)
    assert np.allclose(normal[15:17, 15:17, :2], 0.0, atol=0.02) and (normal[15:17, 15:17, 2] > 0.85).all()
    sky = np.s_[4:8, 0:3]  # the left edge: nothing but sky
    assert np.allclose(albedo[sky], 0.3, atol=1e-3) and np.allclose(normal[sky], 0.0)

