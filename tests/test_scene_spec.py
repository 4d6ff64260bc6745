"""The scene spec (scene.json): one description that scene.xml and scene.pov are written from,
and that the exporters read back; older job folders without it still export."""

from __future__ import annotations

import dataclasses
import json
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from icefarm.scene import mitsuba as mx, povray as pov
from icefarm.scene.config import ice_medium
from icefarm.scene.spec import SceneSpec, read_spec
from icefarm.scene.write import JobScene, build_spec, read_scene_spec, write_scenes

FLIP = np.array([1.0, 1.0, -1.0])  # POV-Ray's left-handed world


def floats(text):
    return np.array([float(x) for x in re.split(r"[\s,<>]+", text.strip()) if x])


@pytest.fixture
def spec(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config(views=["three_quarter", "front"], environment={"exposure": 0.5, "sun_elevation": 30})
    return build_spec(tmp_path, JobScene(box, ice, impurity=0.3), config)


def test_scene_xml_says_what_the_spec_says(spec):
    root = ET.fromstring(mx.scene_xml(spec))
    sensors = root.findall("sensor")
    assert len(sensors) == len(spec.cameras) == 2
    for sensor, camera in zip(sensors, spec.cameras):
        look = sensor.find("transform/lookat")
        for name in ("origin", "target", "up"):
            np.testing.assert_allclose(floats(look.get(name)), getattr(camera, name), rtol=1e-8, atol=1e-12)
        assert float(sensor.find("float[@name='fov']").get("value")) == pytest.approx(camera.fov_x, rel=1e-8)
    sun = root.find("emitter[@type='directional']")
    np.testing.assert_allclose(-floats(sun.find("vector").get("value")), spec.sun.direction, rtol=1e-8)
    np.testing.assert_allclose(floats(sun.find("rgb").get("value")), spec.sun.irradiance, rtol=1e-8)
    assert float(root.find("emitter[@type='envmap']/float").get("value")) == pytest.approx(spec.sky.scale)
    m = floats(root.find("shape[@id='ground']/transform/matrix").get("value")).reshape(4, 4)
    local = np.array([[-1.0, -1.0, 0.0, 1.0], [1.0, -1.0, 0.0, 1.0], [1.0, 1.0, 0.0, 1.0], [-1.0, 1.0, 0.0, 1.0]])
    np.testing.assert_allclose((local @ m.T)[:, :3], spec.ground.corners, rtol=1e-7, atol=1e-9)
    assert root.find("shape[@id='ice']/medium") is not None and ice_medium(spec.ice) is not None


def test_scene_pov_says_what_the_spec_says(spec):
    text = pov.scene_pov(spec, object_inc="object.inc", ice_inc="ice.inc")
    cameras = re.findall(r"camera \{ perspective location (<[^>]*>).*?sky (<[^>]*>) angle (\S+) "
                         r"look_at (<[^>]*>)", text)
    assert len(cameras) == len(spec.cameras)
    for (origin, up, angle, target), camera in zip(cameras, spec.cameras):
        np.testing.assert_allclose(floats(origin), camera.origin * FLIP, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(floats(target), camera.target * FLIP, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(floats(up), camera.up * FLIP, atol=1e-12)
        assert float(angle) == pytest.approx(camera.fov_x, rel=1e-8)
    sun = re.search(r"light_source \{ (<[^>]*>) color rgb (<[^>]*>) parallel point_at <0, 0, 0> \}", text)
    np.testing.assert_allclose(floats(sun[1]) / 1e4, spec.sun.direction * FLIP, rtol=1e-6)
    np.testing.assert_allclose(floats(sun[2]) * np.pi, spec.sun.irradiance, rtol=1e-5)  # lights are over pi
    corners = floats(re.search(r"polygon \{ 5, (.*)\n", text)[1]).reshape(5, 3)
    np.testing.assert_allclose(corners[:4], spec.ground.corners * FLIP, rtol=1e-7, atol=1e-9)
    assert f"emission rgb {spec.sky.scale:.6g}" in text


def test_the_spec_reads_back_as_written_and_writes_the_same_scene(spec, tmp_path):
    back = SceneSpec.from_json(json.loads(json.dumps(spec.to_json())))
    assert back.to_json() == spec.to_json()
    # scene.json holds the sun's direction as a unit vector; the writers use it as computed
    np.testing.assert_allclose(back.sun.direction, spec.sun.direction, rtol=1e-15)
    back = dataclasses.replace(back, sun=dataclasses.replace(back.sun, direction=spec.sun.direction))
    assert mx.scene_xml(back) == mx.scene_xml(spec)
    assert pov.scene_pov(back, object_inc="o", ice_inc="i") == pov.scene_pov(spec, object_inc="o", ice_inc="i")


def test_write_scenes_writes_scene_json_and_views_from_the_spec(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path, JobScene(box, ice), tiny_config(views=["three_quarter", "ice"]))
    spec = read_spec(tmp_path / "scene.json")
    assert spec.to_json() == files.spec.to_json() and spec.object_file == "object.ply" and spec.ice_file == "ice.ply"
    assert files.xml.read_text() == mx.scene_xml(files.spec)
    views = json.loads((tmp_path / "views.json").read_text())
    assert [v["name"] for v in views] == [v.name for v in spec.views] == ["three_quarter", "ice"]
    assert [v["icicle_px"] for v in views] == [v.icicle_px for v in spec.views]
    assert files.ground_height == pytest.approx(spec.ground.centre @ spec.up)


def test_a_folder_without_scene_json_reads_from_scene_xml_and_exports(tmp_path, box_with_icicles, tiny_config):
    """Jobs rendered before scene.json: the exporters read scene.xml (icefarm.scene.legacy)."""
    from icefarm.export.gltf import write_glb

    box, ice = box_with_icicles()
    write_scenes(tmp_path, JobScene(box, ice, impurity=0.5), tiny_config(views=["three_quarter", "front"]))
    (tmp_path / "params.yaml").write_text(yaml.safe_dump({"water": {"gravity": [0.0, -1.0, 0.0]}}))
    new = read_scene_spec(tmp_path)
    (tmp_path / "scene.json").unlink()
    old = read_scene_spec(tmp_path)
    assert [v.name for v in old.views] == [v.name for v in new.views] == ["three_quarter", "front"]
    assert old.resolution == new.resolution
    for a, b in zip(old.cameras, new.cameras, strict=True):
        np.testing.assert_allclose(a.origin, b.origin, atol=1e-7)
        assert a.fov_y == pytest.approx(b.fov_y, abs=1e-6)
    np.testing.assert_allclose(old.sun.direction, new.sun.direction, atol=1e-7)
    np.testing.assert_allclose(old.ground.corners, new.ground.corners, atol=1e-6)
    assert old.ice.absorption == pytest.approx(new.ice.absorption, rel=1e-6)
    assert old.ice.scattering == pytest.approx(new.ice.scattering, rel=1e-6)
    assert write_glb(tmp_path, tmp_path / "old.glb").stat().st_size > 0
    (tmp_path / "scene.xml").write_text("<scene><nothing/></scene>")
    from icefarm.errors import InputError

    with pytest.raises(InputError, match="not a scene.xml written by icefarm"):
        read_scene_spec(tmp_path)
