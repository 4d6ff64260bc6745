"""Milky bands under the ripple crests of impure ice: where stage 4's ripples put them (the
crest property of ice.ply), how the render reads them (clear and frosted ice blended per
vertex in scene.xml), and that clear ice stays clear."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from icefarm import artifacts
from icefarm.errors import InputError
from icefarm.jobdir import ICE_BANDS
from icefarm.scene import mitsuba as mx
from icefarm.scene.config import render_config_from_dict
from icefarm.scene.spec import BAND_ALPHA, BAND_ATTRIBUTE, SceneSpec
from icefarm.scene.write import JobScene, build_spec, write_scenes
from icefarm.stages.surface.profile import profile_args
from icefarm.stages.surface.ripples import carve_ripples, ripple_bands


def _icicle(kit, **changes):
    """A 15 cm icicle under a sphere at the defaults (with ``changes``): its ice and surface group."""
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    surface, glaze = kit.groups(**changes)
    return kit.ice(obj, kit.dry(obj), drips, kit.straight(drips.positions, [0.15]), surface, glaze), surface


def test_bands_lie_under_the_crests_and_nowhere_off_the_icicle(surface_kit):
    ice, surface = _icicle(surface_kit)
    prof = profile_args(surface)
    bands = ripple_bands(ice.vertices, ice.axes, prof)
    assert bands.dtype == np.float32 and bands.shape == (len(ice.vertices),)
    assert bands.min() >= 0.0 and bands.max() <= 1.0 and bands.max() > 0.9
    # The ripple would push a vertex outward on a crest, inward in a trough: the bands follow it.
    push = carve_ripples(ice.vertices, ice.axes, prof) - ice.vertices
    axis_x = ice.axes.points[:, [0, 2]].mean(axis=0)
    outward = ice.vertices[:, [0, 2]] - axis_x
    signed = np.einsum("ij,ij->i", push[:, [0, 2]], outward)
    rippled = np.abs(signed) > 1e-12
    crest, trough = rippled & (signed > 0), rippled & (signed < 0)
    # (by a share: the ripple's patches, deep on some stretches and calm on others, scale both)
    assert bands[crest].mean() > 1.3 * bands[trough].mean()
    # Off the icicle (the sphere it hangs from, away from the root) there are none.
    sphere = surface_kit.sphere().vertices
    far = np.linalg.norm(sphere[:, [0, 2]] - axis_x, axis=1) > 0.05
    assert far.any() and not ripple_bands(sphere, ice.axes, prof)[far].any()


def test_clear_ice_has_no_bands(surface_kit):
    ice, surface = _icicle(surface_kit, surface__impurity=0.0)
    assert ripple_bands(ice.vertices, ice.axes, profile_args(surface)) is None
    assert ice.bands is None  # nor does stage 4 carry any


def test_stage_4_carries_the_bands_that_its_finished_ice_reads(surface_kit):
    # Read off the carve itself, through the clean-up: what ripple_bands reads off the result.
    ice, surface = _icicle(surface_kit)
    assert ice.bands is not None and ice.bands.dtype == np.float32 and ice.bands.shape == (len(ice.vertices),)
    again = ripple_bands(ice.vertices, ice.axes, profile_args(surface))
    assert (ice.bands > 0.5).sum() > 100
    assert np.mean(np.abs(ice.bands - again) < 1e-4) > 0.999
    assert np.abs(ice.bands - again).max() < 0.1


def test_ice_ply_keeps_the_bands_where_mitsuba_finds_them(tmp_path, box_with_icicles):
    import mitsuba

    _, ice = box_with_icicles()
    bands = np.linspace(0.0, 1.0, len(ice.vertices), dtype=np.float32)
    ice.vertex_attributes[ICE_BANDS] = bands
    path = tmp_path / "ice.ply"
    artifacts.write_mesh(path, ice)
    back = artifacts.read_ice_mesh(path)
    assert np.array_equal(back.vertex_attributes[ICE_BANDS], bands)
    mitsuba.set_variant("scalar_rgb")
    shape = mitsuba.load_dict({"type": "ply", "filename": str(path)})
    assert shape.has_attribute(BAND_ATTRIBUTE)
    assert np.allclose(np.array(mitsuba.traverse(shape)[BAND_ATTRIBUTE]), bands)


def _ice_bsdf(spec: SceneSpec) -> ET.Element:
    root = ET.fromstring(mx.scene_xml(spec))
    return next(s for s in root.iter("shape") if s.get("id") == "ice").find("bsdf")


def test_scene_blends_frosted_ice_by_the_crests(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    ice.vertex_attributes[ICE_BANDS] = np.linspace(0.0, 1.0, len(ice.vertices), dtype=np.float32)
    config = tiny_config()
    spec = build_spec(tmp_path, JobScene(box, ice, impurity=0.5), config)
    assert spec.ice.shimmer == pytest.approx(0.5 * config.ice.shimmer) and spec.ice.shimmer > 0
    bsdf = _ice_bsdf(spec)
    assert bsdf.get("type") == "blendbsdf"
    weight = bsdf.find("texture")
    assert weight.get("type") == "mesh_attribute" and weight.get("name") == "weight"
    assert weight.find("string").get("value") == BAND_ATTRIBUTE
    assert float(weight.find("float").get("value")) == pytest.approx(spec.ice.shimmer)
    clear, frosted = bsdf.findall("bsdf")
    assert clear.get("type") == "dielectric" and frosted.get("type") == "roughdielectric"
    assert float(frosted.find("float[@name='alpha']").get("value")) == pytest.approx(BAND_ALPHA)
    assert SceneSpec.from_json(spec.to_json()).ice.shimmer == pytest.approx(spec.ice.shimmer)


@pytest.mark.parametrize("case", ["no bands", "pure water", "shimmer off"])
def test_clear_ice_renders_as_one_dielectric(tmp_path, box_with_icicles, tiny_config, case):
    box, ice = box_with_icicles()
    if case != "no bands":
        ice.vertex_attributes[ICE_BANDS] = np.ones(len(ice.vertices), dtype=np.float32)
    config = tiny_config(ice={"shimmer": 0.0}) if case == "shimmer off" else tiny_config()
    spec = build_spec(tmp_path, JobScene(box, ice, impurity=0.0 if case == "pure water" else 0.5), config)
    assert spec.ice.shimmer == 0.0
    assert _ice_bsdf(spec).get("type") == "dielectric"
    # A scene.json written before the shimmer reads as clear.
    data = spec.to_json()
    del data["ice"]["shimmer"]
    assert SceneSpec.from_json(data).ice.shimmer == 0.0


def test_shimmer_outside_0_to_1_is_refused():
    with pytest.raises(InputError, match="shimmer"):
        render_config_from_dict({"ice": {"shimmer": 1.5}})


@pytest.mark.slow  # renders
def test_the_bands_change_the_rendered_ice(tmp_path, mi, box_with_icicles, tiny_config):
    from icefarm.jobdir import RENDER_EXR
    from icefarm.scene.images import read_image
    from icefarm.scene.render import render_job

    box, ice = box_with_icicles()
    config = tiny_config(denoise="none")
    pictures = {}
    for name, bands in (("clear", None), ("milky", 1.0)):
        if bands is not None:
            ice.vertex_attributes[ICE_BANDS] = np.full(len(ice.vertices), bands, dtype=np.float32)
        out = tmp_path / name
        render_job(out, config, write_scenes(out, JobScene(box, ice, impurity=1.0), config))
        pictures[name] = read_image(out / RENDER_EXR)
    assert np.isfinite(pictures["milky"]).all()
    assert np.abs(pictures["milky"] - pictures["clear"]).mean() > 1e-3
