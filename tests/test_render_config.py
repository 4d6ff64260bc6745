"""Render configs: the named ones, YAML files and overrides, refusals, materials, views, the ice's absorption."""

from __future__ import annotations

import numpy as np
import pytest

from icefarm.errors import InputError
from icefarm.scene.config import (
    View,
    config_names,
    load_render_config,
    parse_view,
    render_config_from_dict,
    render_config_to_dict,
)
from icefarm.scene.material import Material, material_from_dict


def test_named_configs_load_and_differ():
    assert {"preview", "lookdev", "final"} <= set(config_names())
    preview, lookdev, final = (load_render_config(n) for n in ("preview", "lookdev", "final"))
    assert preview.resolution == (320, 240) and preview.name == "preview"
    assert final.resolution == (1920, 1080)
    assert preview.spp < lookdev.spp < final.spp
    assert preview.ice.ior == pytest.approx(1.31)
    assert all(isinstance(v, View) for v in final.views) and len(final.views) > 1


def test_config_round_trips_through_dict():
    config = load_render_config("final", {"ice.roughness": 0.05, "views": [[10, -5], "front"]})
    again = render_config_from_dict(render_config_to_dict(config), name=config.name)
    assert again == config
    assert config.ice.roughness == 0.05 and config.views[0] == View("az10_el-5", 10.0, -5.0)


def test_unknown_key_names_nearest():
    with pytest.raises(InputError, match="resolution"):
        render_config_from_dict({"resolutoin": [10, 10]})
    with pytest.raises(InputError, match="ice.roughness"):
        render_config_from_dict({"ice": {"rougness": 0.1}})
    with pytest.raises(InputError, match="environment.sun_strength"):
        render_config_from_dict({"environment.sun_strenght": 2})


@pytest.mark.parametrize("values, words", [
    ({"spp": 0}, ["spp", "0", "integer"]),
    ({"spp": 2.5}, ["spp", "2.5"]),
    ({"resolution": "big"}, ["resolution", "'big'", "width, height"]),
    ({"renderer": "blender"}, ["renderer", "mitsuba | povray | both"]),
    ({"variant": "llvm_rgb"}, ["variant", "llvm_ad_rgb"]),
    ({"views": ["frnt"]}, ["views[0]", "'front'"]),
    ({"views": [[0, 95]]}, ["views[0]", "elevation"]),
    ({"ice": {"roughness": 2}}, ["ice.roughness", "2", "[0, 1]"]),
    ({"ice": {"tint": [1, 1]}}, ["ice.tint", "3 numbers"]),
    ({"environment": {"ground": "grass"}}, ["environment.ground", "checker"]),
    ({"environment": {"sky": "missing.exr"}}, ["environment.sky", "no such file"]),
    ({"ice": 1.3}, ["ice", "mapping"]),
])
def test_bad_values_are_refused_with_key_value_and_expectation(values, words):
    with pytest.raises(InputError) as info:
        render_config_from_dict(values)
    for word in words:
        assert word in str(info.value)


def test_yaml_file_and_overrides(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("renderer: both\nspp: 7\nice: {roughness: 0.2}\n")
    config = load_render_config(path, {"spp": 9})
    assert (config.name, config.renderer, config.spp, config.ice.roughness) == ("mine", "both", 9, 0.2)
    path.write_text("spp: [\n")
    with pytest.raises(InputError, match="cannot read"):
        load_render_config(path)
    with pytest.raises(InputError, match="preview"):
        load_render_config("previw")


def test_material_validation():
    assert material_from_dict(None).type == "diffuse" and material_from_dict(None) == Material()
    assert material_from_dict({"type": "metal", "metal": "Cu"}).metal == "Cu"
    with pytest.raises(InputError, match="color"):
        material_from_dict({"colour": [1, 0, 0]})
    with pytest.raises(InputError, match="material.roughness"):
        material_from_dict({"roughness": -1})


def test_parse_view_forms():
    assert parse_view("v", "side") == View("side", 90.0, 5.0)
    assert parse_view("v", {"azimuth": 1, "elevation": 2, "name": "x"}) == View("x", 1.0, 2.0)


def test_absorption_accepts_per_meter_or_a_colour_at_a_distance():
    a = render_config_from_dict({"ice": {"absorption": {"color": [0.5, 0.8, 0.9], "distance": 0.1}}}).ice.absorption
    np.testing.assert_allclose(a, -np.log([0.5, 0.8, 0.9]) / 0.1)
    assert render_config_from_dict({"ice.absorption": [1, 2, 3]}).ice.absorption == (1.0, 2.0, 3.0)
    assert render_config_from_dict({"ice.absorption": 0}).ice.absorption == (0.0, 0.0, 0.0)
    for bad in ({"color": [0, 1, 1], "distance": 0.1}, {"color": [0.5, 0.5, 0.5], "distance": 0},
                {"color": [0.5, 0.5]}, [-1, 0, 0], "blue"):
        with pytest.raises(InputError, match="ice.absorption"):
            render_config_from_dict({"ice": {"absorption": bad}})
    with pytest.raises(InputError, match="ice.scattering"):
        render_config_from_dict({"ice": {"scattering": -1}})
    config = load_render_config("lookdev", {"views": [{"azimuth": 200, "elevation": 5, "frame": "ice"}]})
    assert config.views[0].frame == "ice"
    assert render_config_from_dict(render_config_to_dict(config), name=config.name) == config
    with pytest.raises(InputError, match="frame"):
        render_config_from_dict({"views": [{"azimuth": 0, "elevation": 0, "frame": "icicles"}]})
