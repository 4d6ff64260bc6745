"""Scene files for Mitsuba and POV-Ray: the file contract, sky, materials, normals and winding,
the ice's medium, the ground."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

from icefarm.scene import povray as pov
from icefarm.scene.config import load_render_config
from icefarm.scene.images import read_image
from icefarm.scene.material import material_from_dict
from icefarm.scene.render import render_job
from icefarm.scene.write import JobScene, write_scenes


def test_scene_files_follow_the_contract(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path, JobScene(box, ice), tiny_config())
    for name in ("scene.xml", "scene.pov", "object.ply", "ice.ply", "object.inc", "ice.inc"):
        assert (tmp_path / name).is_file(), name
    root = ET.parse(files.xml).getroot()
    assert root.tag == "scene" and root.get("version") == "3.0.0"
    names = [e.get("value") for e in root.iter("string") if e.get("name") == "filename"]
    assert sorted(names) == ["ice.ply", "object.ply", files.sky.name]
    assert all((tmp_path / n).is_file() and "/" not in n for n in names)  # relative, in the folder
    assert files.sky.suffix == ".exr" and f'"{files.sky.name}"' in files.pov.read_text()
    ice_bsdf = root.find("shape[@id='ice']/bsdf")
    assert ice_bsdf.get("type") == "dielectric"
    assert ice_bsdf.find("string[@name='int_ior']").get("value") == "water ice"
    assert len(root.findall("sensor")) == 1 and files.cameras[0].fov_y == 30.0
    assert trimesh.load(tmp_path / "object.ply").vertex_normals.shape[1] == 3
    text = files.pov.read_text()
    assert "#version 3.7" in text and "ior 1.31" in text and "fresnel" in text and "fade_distance" in text
    assert "normal_vectors" in (tmp_path / "ice.inc").read_text()


def test_custom_sky_image_is_copied_next_to_the_scene(tmp_path, box_with_icicles, tiny_config):
    from icefarm.scene.images import write_exr

    write_exr(tmp_path / "studio.exr", np.full((8, 16, 3), 0.5, np.float32))
    (tmp_path / "look.yaml").write_text("environment: {sky: studio.exr}\n")  # relative to the YAML
    config = tiny_config(base=load_render_config(tmp_path / "look.yaml"))
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path / "job", JobScene(box, ice), config)
    assert files.sky == tmp_path / "job" / "sky_studio.exr" and files.sky.is_file()
    assert "sky_studio.exr" in files.xml.read_text()


def test_rough_ice_other_ior_and_no_ice(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path / "a", JobScene(box, ice), tiny_config(ice={"roughness": 0.1, "ior": 1.5}))
    bsdf = ET.parse(files.xml).getroot().find("shape[@id='ice']/bsdf")
    assert bsdf.get("type") == "roughdielectric"
    assert bsdf.find("float[@name='int_ior']").get("value") == "1.5"
    assert bsdf.find("float[@name='alpha']").get("value") == "0.1"
    metal = material_from_dict({"type": "metal"})
    files = write_scenes(tmp_path / "b", JobScene(box, None, material=metal), tiny_config())
    root = ET.parse(files.xml).getroot()
    assert root.find("shape[@id='ice']") is None and files.ice_ply is None
    assert root.find("shape[@id='object']/bsdf/bsdf").get("type") == "roughconductor"


def test_inward_ice_gets_flipped_normals(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    ice.invert()
    files = write_scenes(tmp_path, JobScene(box, ice), tiny_config())
    flag = ET.parse(files.xml).getroot().find("shape[@id='ice']/boolean[@name='flip_normals']")
    assert flag is not None and flag.get("value") == "true"


def test_ground_level_places_the_ground_plane(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config()
    default = write_scenes(tmp_path / "default", JobScene(box, ice), config)
    level = 0.0  # the box's underside: the icicles would reach below it
    files = write_scenes(tmp_path / "level", JobScene(box, ice, ground_level=level), config)

    def ground_height(xml):
        m = np.array([float(x) for x in ET.parse(xml).getroot().find(
            "shape[@id='ground']/transform/matrix").get("value").split()]).reshape(4, 4)
        return m[1, 3]  # y is up

    assert ground_height(default.xml) == pytest.approx(ice.vertices[:, 1].min(), abs=1e-3)
    assert ground_height(files.xml) == pytest.approx(level, abs=1e-9)
    assert all(c.origin[1] > level for c in files.cameras)
    assert f"{level:.9g}" in files.pov.read_text().split("polygon {")[1].split("\n")[0]
    with pytest.raises(ValueError, match="ground_level"):
        write_scenes(tmp_path / "bad", JobScene(box, ice, ground_level=float("nan")), config)


def test_mesh2_text_holds_the_mesh_in_povray_handedness(tmp_path):
    rng = np.random.default_rng(3)
    vertices = rng.normal(size=(50, 3)) * [0.2, 3.0, 0.01]
    vertices[0] = [0.0, -4e-7, 12.5]  # rounds to zero (no "-0"), and a wide number
    vertices[1] = [-2500.0, 0.0, 0.0]  # over 2^31 micrometres
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[0] = [0.0, -1e-6, 1.0]
    faces = rng.integers(0, 50, size=(70, 3))
    pov.write_mesh2(tmp_path / "m.inc", "M", vertices, normals, faces, inside=True)
    text = (tmp_path / "m.inc").read_text()
    assert text.startswith("#declare M = mesh2 {") and "inside_vector" in text
    assert text.endswith("scale 1e-06\n}\n")

    def block(name):
        body = text.split(name + " {")[1].split("}")[0]
        count, rows = body.split(",", 1)
        numbers = [x.lstrip("<").rstrip(" >") for r in rows.replace("\n", "").split(">,")
                   for x in r.split(",")]
        assert all(float(x) != 0 for x in numbers if x.startswith("-")), "negative zero written"
        assert len({len(x) for x in numbers}) == 1, "numbers of different widths"
        values = np.array([float(x) for x in numbers]).reshape(-1, 3)
        assert int(count) == len(values)
        return values

    np.testing.assert_allclose(block("vertex_vectors") * 1e-6, vertices * [1, 1, -1], atol=5e-7)
    np.testing.assert_allclose(block("normal_vectors"), normals * [1, 1, -1], atol=5e-5)
    np.testing.assert_array_equal(block("face_indices"), faces)


def test_vector_lines_refuses_what_it_cannot_write():
    with pytest.raises(ValueError, match="integers"):
        pov.vector_lines(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="smaller than 10"):
        pov.vector_lines(np.full((1, 3), 12.0), unit=True)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        pov.vector_lines(np.zeros((2, 2), dtype=int))


def test_smooth_normals_are_the_ones_mitsuba_computes(tmp_path):
    """Mitsuba computes the ice's normals when it loads ice.ply; POV-Ray and the exports get
    these (`SceneFiles.ice_normals`): they must agree."""
    import mitsuba as mi

    from icefarm.scene.geometry import smooth_normals, write_ply
    from icefarm.scene.variants import pick_variant

    mesh = trimesh.creation.icosphere(3, 0.1)
    mesh.vertices += np.random.default_rng(5).normal(scale=0.004, size=mesh.vertices.shape)
    mesh.vertices *= [1.0, 2.5, 0.6]  # uneven triangles: angle and area weights differ
    write_ply(tmp_path / "m.ply", mesh.vertices, mesh.faces)
    mi.set_variant(pick_variant("auto"))
    scene = mi.load_dict({"type": "scene", "m": {"type": "ply", "id": "m", "filename": str(tmp_path / "m.ply")}})
    ours = smooth_normals(mesh.vertices, mesh.faces)
    mitsubas = np.array(mi.traverse(scene.shapes()[0])["vertex_normals"], dtype=np.float64).reshape(-1, 3)
    np.testing.assert_allclose(mitsubas, ours, atol=2e-5)
    area_weighted = np.zeros_like(ours)
    np.add.at(area_weighted, mesh.faces.ravel(), np.repeat(mesh.triangles_cross, 3, axis=0))
    area_weighted /= np.linalg.norm(area_weighted, axis=1, keepdims=True)
    assert np.abs(area_weighted - ours).max() > 1e-3  # the weighting is really different


def test_winding_is_read_from_the_outermost_vertex(box_with_icicles):
    from icefarm.scene.geometry import signed_volume, winds_inward

    _, ice = box_with_icicles()  # five separate cones
    blob = trimesh.creation.icosphere(subdivisions=3)
    blob.vertices *= [1.0, 0.4, 2.5]
    for mesh in (ice, blob, trimesh.creation.box()):  # a box: flat faces around its corner
        assert signed_volume(mesh.vertices, mesh.faces) > 0
        assert not winds_inward(mesh.vertices, mesh.faces)
        inverted = mesh.copy()
        inverted.invert()
        assert winds_inward(inverted.vertices, inverted.faces)


def medium_of(xml: Path):
    root = ET.parse(xml).getroot()
    return root.find("integrator").get("type"), root.find("shape[@id='ice']/medium")


def test_ice_holds_an_absorbing_medium_that_scatters_with_impurity(tmp_path, box_with_icicles, tiny_config):
    box, ice = box_with_icicles()
    config = tiny_config()
    absorption = np.array(config.ice.absorption)
    for impurity in (0.0, 0.6):
        files = write_scenes(tmp_path / str(impurity), JobScene(box, ice, impurity=impurity), config)
        integrator, medium = medium_of(files.xml)
        assert integrator == "volpath" and medium.get("type") == "homogeneous"
        assert medium.get("name") == "interior"
        scale = float(medium.find("float[@name='scale']").get("value"))
        sigma_t = scale * np.array([float(x) for x in medium.find("rgb[@name='sigma_t']").get("value").split(",")])
        albedo = np.array([float(x) for x in medium.find("rgb[@name='albedo']").get("value").split(",")])
        scattering = config.ice.scattering * impurity
        np.testing.assert_allclose(sigma_t, absorption + scattering, rtol=1e-6)
        np.testing.assert_allclose(albedo * sigma_t, scattering, atol=1e-6)
    # No absorption and pure water: no medium, the plain path tracer.
    files = write_scenes(tmp_path / "none", JobScene(box, ice), tiny_config(ice={"absorption": [0, 0, 0]}))
    assert medium_of(files.xml) == ("path", None)
    with pytest.raises(ValueError, match="impurity"):
        write_scenes(tmp_path / "bad", JobScene(box, ice, impurity=1.5), config)


def test_scene_xml_loads_with_the_medium_icepath_gets_from_the_spec(tmp_path, box_with_icicles, tiny_config):
    """icepath takes the ice's medium from the spec; Mitsuba's own integrators from scene.xml:
    the same coefficients."""
    import mitsuba as mi

    from icefarm.scene.config import ice_medium
    from icefarm.scene.integrator import medium_coefficients
    from icefarm.scene.variants import pick_variant

    box, ice = box_with_icicles()
    config = tiny_config()
    files = write_scenes(tmp_path, JobScene(box, ice, impurity=0.5), config)
    medium = ice_medium(files.spec.ice)
    np.testing.assert_allclose(medium.absorption, config.ice.absorption)
    assert medium.scattering == pytest.approx(config.ice.scattering * 0.5)
    mi.set_variant(pick_variant("auto"))
    scene = mi.load_file(str(files.xml))
    sigma_a, sigma_s = medium_coefficients(scene, "ice")
    np.testing.assert_allclose(sigma_a, medium.absorption, rtol=1e-4)
    np.testing.assert_allclose(sigma_s, [medium.scattering] * 3, rtol=1e-4)
    assert medium_coefficients(scene, "object") is None


@pytest.mark.slow
def test_povray_scene_has_the_fade_and_the_cloudy_medium(tmp_path, box_with_icicles, tiny_config, assert_not_blank):
    box, ice = box_with_icicles()
    config = tiny_config(renderer="povray", resolution=[40, 30])
    files = write_scenes(tmp_path / "clear", JobScene(box, ice, impurity=0.0), config)
    text = files.pov.read_text()
    a = np.array(config.ice.absorption)
    fade = text.split("interior {")[1].split("}")[0]
    assert "fade_power 1001" in fade and f"fade_distance {1 / a.max():.6g}" in fade
    colour = np.array([float(x) for x in fade.split("fade_color rgb <")[1].split(">")[0].split(",")])
    # POV-Ray: exp(-(1 - fade_color) d / fade_distance) is Beer-Lambert with these coefficients.
    np.testing.assert_allclose((1 - colour) * a.max(), a, rtol=1e-5)
    assert "media" not in text and "Ice_Mesh hollow" not in text
    files = write_scenes(tmp_path / "cloudy", JobScene(box, ice, impurity=0.6), config)
    text = files.pov.read_text()
    assert "Ice_Mesh hollow" in text and f"scattering {{ 1, rgb {config.ice.scattering * 0.6:.6g} }}" in text
    if shutil.which("povray") is None:
        pytest.skip("povray is not installed (apt-get install povray)")
    for name in ("clear", "cloudy"):
        render_job(tmp_path / name, config)
        assert_not_blank(read_image(tmp_path / name / "render_povray.png"))
