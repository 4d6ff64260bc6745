"""Scenes and renders: Mitsuba XML, POV-Ray, render configs, variant choice."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

from icefarm.errors import InputError
from icefarm.scene import povray as pov
from icefarm.scene.camera import frame_view, world_frame
from icefarm.scene.config import (RenderConfig, View, config_names, load_render_config, parse_view,
                                  render_config_from_dict, render_config_to_dict)
from icefarm.scene.images import read_image
from icefarm.scene.material import Material, material_from_dict
from icefarm.scene.render import render_job, write_scenes
from icefarm.scene.variants import choose_variant, find_libllvm, llvm_version

ROOT = Path(__file__).resolve().parents[1]
MITSUBA_CLI = Path(sys.executable).parent / "mitsuba"
TINY = {"resolution": [48, 36], "spp": 4, "max_depth": 6}


def box_with_icicles(gravity=(0.0, -1.0, 0.0)):
    """A 30 cm box and five cones hanging from its underside along ``gravity``."""
    g = np.asarray(gravity, dtype=float) / np.linalg.norm(gravity)
    box = trimesh.creation.box(extents=(0.3, 0.1, 0.2))
    box.apply_translation((0.0, 0.05, 0.0))
    cones = []
    for i, x in enumerate(np.linspace(-0.12, 0.12, 5)):
        cone = trimesh.creation.cone(radius=0.012, height=0.06 + 0.03 * (i % 3), sections=24)
        cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # tip -Y
        cone.apply_translation((x, 0.0, 0.05 * (1 if i % 2 else -1)))
        cones.append(cone)
    ice = trimesh.util.concatenate(cones)
    # Rotate the Y-up test scene so that -Y goes to gravity.
    turn = trimesh.geometry.align_vectors((0.0, -1.0, 0.0), g)
    for mesh in (box, ice):
        mesh.apply_transform(turn)
    return box, ice


def tiny_config(**changes) -> RenderConfig:
    return render_config_from_dict({**TINY, **changes}, base=load_render_config("preview"))


def assert_not_blank(pixels: np.ndarray) -> None:
    rgb = pixels[..., :3]
    assert np.isfinite(rgb).all()
    assert rgb.max() > 0.05, "image is black"
    assert rgb.std() > 0.01, "image is flat"


# ------------------------------------------------------------------ render configs
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


# ------------------------------------------------------------------ variants
def test_llvm_version_from_names():
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert llvm_version("/usr/lib/llvm-18/lib/libLLVM.so") == 18
    assert llvm_version("/usr/lib/libLLVM.so") is None
    assert llvm_version("/usr/lib/libLLVMSupport.a") is None


def test_find_libllvm_refuses_old_versions(tmp_path):
    for name in ("libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM-16.so.1", "libLLVM.so"):
        (tmp_path / name).write_bytes(b"")
    assert find_libllvm([tmp_path]) is None
    (tmp_path / "libLLVM-17.so").write_bytes(b"")
    (tmp_path / "libLLVM.so.19.1").write_bytes(b"")
    assert find_libllvm([tmp_path]) == tmp_path / "libLLVM.so.19.1"
    assert find_libllvm([tmp_path / "missing"]) is None


def test_choose_variant_order_and_refusals():
    assert choose_variant("auto", cuda=False, llvm=False) == "scalar_rgb"
    assert choose_variant("auto", cuda=False, llvm=True) == "llvm_ad_rgb"
    assert choose_variant("auto", cuda=True, llvm=True) == "cuda_ad_rgb"
    assert choose_variant("scalar_rgb", cuda=True, llvm=True) == "scalar_rgb"
    with pytest.raises(InputError, match="llvm_ad_rgb"):
        choose_variant("llvm_ad_rgb", cuda=False, llvm=False)
    with pytest.raises(InputError, match="CUDA"):
        choose_variant("cuda_ad_rgb", cuda=False, llvm=True)


@pytest.mark.slow
@pytest.mark.parametrize("fake", [None, "libLLVM.so.19.1"])
def test_pick_variant_falls_back_to_scalar_without_good_llvm(tmp_path, fake):
    """A fresh process (Dr.Jit reads the path at import): no libLLVM, or a fake one, gives scalar."""
    if fake:
        (tmp_path / fake).write_bytes(b"not a library")
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env.update(CUDA_VISIBLE_DEVICES="", DRJIT_LIBCUDA_PATH=str(tmp_path / "no-libcuda.so"),
               PYTHONPATH=str(ROOT))
    code = ("import os; from icefarm.scene.variants import pick_variant; "
            f"print(pick_variant('auto', search_dirs=[{str(tmp_path)!r}])); "
            "print(os.environ['DRJIT_LIBLLVM_PATH'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    variant, path = out.stdout.split()
    assert variant == "scalar_rgb"
    assert (path == str(tmp_path / fake)) if fake else "nonexistent" in path


# ------------------------------------------------------------------ cameras
@pytest.mark.parametrize("gravity", [(0, -1, 0), (0, 0, -1), (1, 0, 0)])
def test_camera_up_follows_gravity_and_frames_everything(gravity):
    box, ice = box_with_icicles(gravity)
    points = np.vstack([box.vertices, ice.vertices])
    up = world_frame(gravity)[1]
    assert np.allclose(up, -np.asarray(gravity, float))
    ground = float((points @ up).min())
    camera = frame_view(points, gravity, 35.0, -8.0, 4 / 3, ground=ground)
    assert np.allclose(camera.up, up)
    assert camera.origin @ up > ground
    pixels = camera.project(points, 400, 300)
    assert (pixels >= 0).all() and (pixels[:, 0] <= 400).all() and (pixels[:, 1] <= 300).all()
    assert np.ptp(pixels[:, 0]) > 0.8 * 400 or np.ptp(pixels[:, 1]) > 0.8 * 300  # fills the frame
    # Hanging icicles (along gravity) go down the picture.
    tip, root = camera.project(np.array([[0, 0, 0], [0, 0, 0]]) + [up * -0.1, up * 0.0], 400, 300)
    assert tip[1] > root[1]


# ------------------------------------------------------------------ scene files
def test_scene_files_follow_the_contract(tmp_path):
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path, box, ice, tiny_config())
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


def test_custom_sky_image_is_copied_next_to_the_scene(tmp_path):
    from icefarm.scene.images import write_exr

    write_exr(tmp_path / "studio.exr", np.full((8, 16, 3), 0.5, np.float32))
    (tmp_path / "look.yaml").write_text("environment: {sky: studio.exr}\n")  # relative to the YAML
    config = render_config_from_dict(TINY, base=load_render_config(tmp_path / "look.yaml"))
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path / "job", box, ice, config)
    assert files.sky == tmp_path / "job" / "sky_studio.exr" and files.sky.is_file()
    assert "sky_studio.exr" in files.xml.read_text()


def test_rough_ice_other_ior_and_no_ice(tmp_path):
    box, ice = box_with_icicles()
    files = write_scenes(tmp_path / "a", box, ice, tiny_config(ice={"roughness": 0.1, "ior": 1.5}))
    bsdf = ET.parse(files.xml).getroot().find("shape[@id='ice']/bsdf")
    assert bsdf.get("type") == "roughdielectric"
    assert bsdf.find("float[@name='int_ior']").get("value") == "1.5"
    assert bsdf.find("float[@name='alpha']").get("value") == "0.1"
    files = write_scenes(tmp_path / "b", box, None, tiny_config(), object_material={"type": "metal"})
    root = ET.parse(files.xml).getroot()
    assert root.find("shape[@id='ice']") is None and files.ice_ply is None
    assert root.find("shape[@id='object']/bsdf/bsdf").get("type") == "roughconductor"


def test_inward_ice_gets_flipped_normals(tmp_path):
    box, ice = box_with_icicles()
    ice.invert()
    files = write_scenes(tmp_path, box, ice, tiny_config())
    flag = ET.parse(files.xml).getroot().find("shape[@id='ice']/boolean[@name='flip_normals']")
    assert flag is not None and flag.get("value") == "true"


@pytest.mark.slow
def test_mitsuba_command_line_renders_the_scene(tmp_path):
    """scene.xml loads in a separate process with the wheel's `mitsuba` renderer."""
    if not MITSUBA_CLI.is_file():
        pytest.skip(f"no mitsuba command beside {sys.executable}")
    box, ice = box_with_icicles()
    write_scenes(tmp_path, box, ice, tiny_config(views=["three_quarter", "front"]))
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
def test_povray_renders_the_scene(tmp_path):
    if shutil.which("povray") is None:
        pytest.skip("povray is not installed (apt-get install povray)")
    box, ice = box_with_icicles()
    config = tiny_config(renderer="povray", resolution=[40, 30])
    write_scenes(tmp_path, box, ice, config)
    result = render_job(tmp_path, config)
    assert result.variant == "" and result.povray_seconds > 0 and result.seconds == 0
    assert [p.name for p in result.files[:2]] == ["render.exr", "render.png"]
    pixels = read_image(tmp_path / "render_povray.png")
    assert pixels.shape[:2] == (30, 40)
    assert_not_blank(pixels)
    assert_not_blank(read_image(tmp_path / "render.exr"))


def test_povray_missing_is_a_clear_error(tmp_path, monkeypatch):
    box, ice = box_with_icicles()
    config = tiny_config(renderer="both")
    write_scenes(tmp_path, box, ice, config)
    monkeypatch.setattr(pov.shutil, "which", lambda name: None)
    with pytest.raises(InputError, match="apt-get install povray"):
        render_job(tmp_path, config)
    assert not (tmp_path / "render.png").exists()  # refused before any rendering


def test_render_job_writes_linear_exr_and_srgb_png(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config(views=["three_quarter", "below"])
    files = write_scenes(tmp_path, box, ice, config)
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
def test_a_process_pinned_to_one_core_renders(tmp_path):
    """Mitsuba reads EXRs (the sky) with Dr.Jit's pool, which waited forever at one thread."""
    box, ice = box_with_icicles()
    write_scenes(tmp_path, box, ice, tiny_config())
    code = ("import os, sys; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
            "from icefarm.scene.config import load_render_config, render_config_from_dict; "
            "from icefarm.scene.render import render_job; "
            f"config = render_config_from_dict({TINY!r}, base=load_render_config('preview')); "
            "print(render_job(sys.argv[1], config).variant)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True,
                         timeout=180, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    assert_not_blank(read_image(tmp_path / "render.png"))


def test_ice_changes_the_picture_where_it_projects(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config(resolution=[80, 60], spp=8, denoise="none")
    points = np.vstack([box.vertices, ice.vertices])  # same camera for both pictures
    with_ice = write_scenes(tmp_path / "ice", box, ice, config, frame_points=points)
    write_scenes(tmp_path / "bare", box, None, config, frame_points=points)
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


def test_deferred_povray_files_are_whole_when_the_render_returns(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config()
    sync = write_scenes(tmp_path / "sync", box, ice, config)
    files = write_scenes(tmp_path / "bg", box, ice, config, defer_povray=True)
    assert sync.povray_writer is None and files.povray_writer is not None
    assert not (tmp_path / "bg" / "scene.pov").exists() and (tmp_path / "bg" / "scene.xml").is_file()
    result = render_job(tmp_path / "bg", config, files)
    for name in ("scene.pov", "object.inc", "ice.inc", "scene.xml"):
        assert (tmp_path / "bg" / name).read_bytes() == (tmp_path / "sync" / name).read_bytes(), name
    assert result.scene_seconds == pytest.approx(result.write_seconds + result.load_seconds + result.wait_seconds)
    assert result.write_seconds == files.seconds and result.load_seconds > 0
    assert result.povray_write_cpu_seconds > 0
    assert render_job(tmp_path / "sync", config).povray_write_cpu_seconds == 0  # nothing deferred


def test_a_failed_render_still_leaves_whole_povray_files(tmp_path, monkeypatch):
    import icefarm.scene.render as render_module

    box, ice = box_with_icicles()
    config = tiny_config()

    def broken(*args, **kwargs):
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(render_module, "render_mitsuba", broken)
    files = write_scenes(tmp_path, box, ice, config, defer_povray=True)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        render_job(tmp_path, config, files)
    assert "Ice_Mesh" in (tmp_path / "scene.pov").read_text()  # written and finished before the error left
    assert (tmp_path / "ice.inc").read_bytes().endswith(b"}\n")


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


def test_smooth_normals_are_the_ones_mitsuba_computes(tmp_path):
    """POV-Ray gets the ice normals Mitsuba computed on load, or these: they must agree."""
    import mitsuba as mi

    from icefarm.scene.geometry import smooth_normals, write_ply
    from icefarm.scene.render import _vertex_normals
    from icefarm.scene.variants import pick_variant

    mesh = trimesh.creation.icosphere(3, 0.1)
    mesh.vertices += np.random.default_rng(5).normal(scale=0.004, size=mesh.vertices.shape)
    mesh.vertices *= [1.0, 2.5, 0.6]  # uneven triangles: angle and area weights differ
    write_ply(tmp_path / "m.ply", mesh.vertices, mesh.faces)
    mi.set_variant(pick_variant("auto"))
    scene = mi.load_dict({"type": "scene", "m": {"type": "ply", "id": "m", "filename": str(tmp_path / "m.ply")}})
    ours = smooth_normals(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(_vertex_normals(scene, "m"), ours, atol=2e-5)
    area_weighted = np.zeros_like(ours)
    np.add.at(area_weighted, mesh.faces.ravel(), np.repeat(mesh.triangles_cross, 3, axis=0))
    area_weighted /= np.linalg.norm(area_weighted, axis=1, keepdims=True)
    assert np.abs(area_weighted - ours).max() > 1e-3  # the weighting is really different


def test_vector_lines_refuses_what_it_cannot_write():
    with pytest.raises(ValueError, match="integers"):
        pov.vector_lines(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="smaller than 10"):
        pov.vector_lines(np.full((1, 3), 12.0), unit=True)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        pov.vector_lines(np.zeros((2, 2), dtype=int))


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


def test_render_in_passes_matches_one_pass(tmp_path, monkeypatch):
    """Passes with their own seeds average to the same picture as one pass (up to noise)."""
    import icefarm.scene.render as render_module

    box, ice = box_with_icicles()
    config = tiny_config(spp=32)
    write_scenes(tmp_path / "one", box, ice, config)
    write_scenes(tmp_path / "many", box, ice, config)
    render_job(tmp_path / "one", config)
    monkeypatch.setattr(render_module, "PASS_SAMPLES", 48 * 36 * 8)  # four passes of 8 spp
    render_job(tmp_path / "many", config, progress=True)
    a = read_image(tmp_path / "one" / "render.exr")
    b = read_image(tmp_path / "many" / "render.exr")
    assert_not_blank(b)
    assert abs(a.mean() - b.mean()) < 0.03 * a.mean()
    assert not np.array_equal(a, b)  # the passes really sampled anew


def test_winding_is_read_from_the_outermost_vertex():
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


@pytest.mark.slow  # a real Mitsuba render
def test_rough_ice_renders_finite_and_differs_from_clear_ice(tmp_path):
    box, ice = box_with_icicles()
    points = np.vstack([box.vertices, ice.vertices])
    images = {}
    for name, roughness in (("clear", 0.0), ("frosted", 0.3)):
        config = tiny_config(resolution=[64, 48], spp=16, ice={"roughness": roughness})
        files = write_scenes(tmp_path / name, box, ice, config, frame_points=points)
        render_job(tmp_path / name, config)
        images[name] = read_image(tmp_path / name / "render.exr")
        assert_not_blank(images[name])
    samples, _ = trimesh.sample.sample_surface(ice, 4000, seed=1)
    xy = files.cameras[0].project(samples, 64, 48).astype(int)
    on_ice = np.zeros((48, 64), bool)
    on_ice[np.clip(xy[:, 1], 0, 47), np.clip(xy[:, 0], 0, 63)] = True
    diff = np.abs(images["clear"] - images["frosted"]).mean(axis=2)
    assert diff[on_ice].mean() > 2 * diff[~on_ice].mean()  # the ice changed, not just the noise


# ------------------------------------------------------------------ ice that renders as ice
def dense_icicles(count: int = 5, spacing: float = 0.05):
    """A 30 cm box with ``count`` cones hanging from its underside, finely meshed like the
    pipeline's marching-cubes ice (edges of about 1.5 mm), 12 mm radius at the root."""
    box = trimesh.creation.box(extents=(0.3, 0.1, 0.2))
    box.apply_translation((0.0, 0.05, 0.0))
    cones = []
    for i in range(count):
        cone = trimesh.creation.cone(radius=0.012, height=0.08 + 0.02 * (i % 3), sections=48)
        cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # tip -Y
        cone.apply_translation(((i - (count - 1) / 2) * spacing, 0.0, 0.04))
        cones.append(cone)
    ice = trimesh.util.concatenate(cones)
    v, f = trimesh.remesh.subdivide_to_size(ice.vertices, ice.faces, max_edge=0.0015)
    return box, trimesh.Trimesh(v, f, process=False), cones


def cone_widths(camera, cones, width, height):
    """Width in pixels of each cone halfway down, and whether that point is in the frame."""
    right = np.cross(camera.forward, camera.up)
    right /= np.linalg.norm(right)
    out = []
    for cone in cones:
        lo, hi = cone.bounds
        mid = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])
        radius = 0.012 * 0.5  # halfway down the cone
        a, b = camera.project(np.array([mid - radius * right, mid + radius * right]), width, height)
        centre = camera.project(mid[None], width, height)[0]
        inside = 0 <= centre[0] < width and 0 <= centre[1] < height
        out.append((float(np.linalg.norm(a - b)), inside))
    return out


@pytest.mark.slow
def test_lookdev_has_an_ice_view_that_frames_the_icicles(tmp_path):
    import json

    lookdev = load_render_config("lookdev")
    assert [v.frame for v in lookdev.views] == ["all", "ice"]
    config = render_config_from_dict({"resolution": [160, 120]}, base=lookdev)
    box, ice, cones = dense_icicles()
    files = write_scenes(tmp_path, box, ice, config)
    full, zoomed = files.cameras
    assert np.allclose(full.origin, zoomed.origin) and zoomed.fov_x < full.fov_x / 2
    seen_full = cone_widths(full, cones, 160, 120)
    seen_ice = cone_widths(zoomed, cones, 160, 120)
    assert all(inside for _, inside in seen_full) and max(w for w, _ in seen_full) < 8
    in_frame = [w for w, inside in seen_ice if inside]
    assert in_frame and min(in_frame) >= 8  # every icicle it shows is at least 8 px wide
    views = json.loads((tmp_path / "views.json").read_text())
    assert [(v["name"], v["frame"], v["stem"]) for v in views] == [
        ("three_quarter", "all", "render"), ("ice", "ice", "render_view1")]
    assert views[0]["icicle_px"] < 8 and views[1]["icicle_px"] >= 12  # the ice view: icicles 12 px wide at least
    assert files.icicle_px == (views[0]["icicle_px"], views[1]["icicle_px"])
    # Both renderers get the zoomed camera.
    assert f"{zoomed.fov_x:.9g}" in files.xml.read_text() and f"angle {zoomed.fov_x:.9g}" in files.pov.read_text()


@pytest.mark.slow
def test_ice_view_without_ice_or_icicles_still_renders_a_view(tmp_path):
    import json

    config = render_config_from_dict({"resolution": [64, 48]}, base=load_render_config("lookdev"))
    box, _, _ = dense_icicles()
    files = write_scenes(tmp_path / "bare", box, None, config)
    assert len(files.cameras) == 2 and np.allclose(files.cameras[0].origin, files.cameras[1].origin)
    assert [v["icicle_px"] for v in json.loads((tmp_path / "bare" / "views.json").read_text())] == [None, None]
    glaze = box.copy()
    glaze.vertices *= 1.02  # a thin shell: ice, but no icicles
    files = write_scenes(tmp_path / "glaze", box, glaze, config)
    assert files.cameras[1].fov_x < files.cameras[0].fov_x


def medium_of(xml: Path):
    root = ET.parse(xml).getroot()
    return root.find("integrator").get("type"), root.find("shape[@id='ice']/medium")


def test_ice_holds_an_absorbing_medium_that_scatters_with_impurity(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config()
    absorption = np.array(config.ice.absorption)
    for impurity in (0.0, 0.6):
        files = write_scenes(tmp_path / str(impurity), box, ice, config, impurity=impurity)
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
    files = write_scenes(tmp_path / "none", box, ice, tiny_config(ice={"absorption": [0, 0, 0]}))
    assert medium_of(files.xml) == ("path", None)
    with pytest.raises(ValueError, match="impurity"):
        write_scenes(tmp_path / "bad", box, ice, config, impurity=1.5)


def test_scene_xml_with_the_medium_loads_and_gives_icepath_its_coefficients(tmp_path):
    import mitsuba as mi

    from icefarm.scene.integrator import medium_coefficients
    from icefarm.scene.variants import pick_variant

    box, ice = box_with_icicles()
    config = tiny_config()
    files = write_scenes(tmp_path, box, ice, config, impurity=0.5)
    mi.set_variant(pick_variant("auto"))
    scene = mi.load_file(str(files.xml))
    sigma_a, sigma_s = medium_coefficients(scene, "ice")
    np.testing.assert_allclose(sigma_a, config.ice.absorption, rtol=1e-4)
    np.testing.assert_allclose(sigma_s, [config.ice.scattering * 0.5] * 3, rtol=1e-4)
    assert medium_coefficients(scene, "object") is None


def _ice_mask(camera, ice, width, height):
    samples, _ = trimesh.sample.sample_surface(ice, 6000, seed=1)
    xy = camera.project(samples, width, height).astype(int)
    mask = np.zeros((height, width), bool)
    mask[np.clip(xy[:, 1], 0, height - 1), np.clip(xy[:, 0], 0, width - 1)] = True
    return mask


def test_impurity_clouds_the_ice_and_impurity_zero_is_clear(tmp_path):
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
        files = write_scenes(tmp_path / name, box, ice, cfg, frame_points=points, impurity=impurity)
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


@pytest.mark.slow
def test_povray_scene_has_the_fade_and_the_cloudy_medium(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config(renderer="povray", resolution=[40, 30])
    files = write_scenes(tmp_path / "clear", box, ice, config, impurity=0.0)
    text = files.pov.read_text()
    a = np.array(config.ice.absorption)
    fade = text.split("interior {")[1].split("}")[0]
    assert "fade_power 1001" in fade and f"fade_distance {1 / a.max():.6g}" in fade
    colour = np.array([float(x) for x in fade.split("fade_color rgb <")[1].split(">")[0].split(",")])
    # POV-Ray: exp(-(1 - fade_color) d / fade_distance) is Beer-Lambert with these coefficients.
    np.testing.assert_allclose((1 - colour) * a.max(), a, rtol=1e-5)
    assert "media" not in text and "Ice_Mesh hollow" not in text
    files = write_scenes(tmp_path / "cloudy", box, ice, config, impurity=0.6)
    text = files.pov.read_text()
    assert "Ice_Mesh hollow" in text and f"scattering {{ 1, rgb {config.ice.scattering * 0.6:.6g} }}" in text
    if shutil.which("povray") is None:
        pytest.skip("povray is not installed (apt-get install povray)")
    for name in ("clear", "cloudy"):
        render_job(tmp_path / name, config)
        assert_not_blank(read_image(tmp_path / name / "render_povray.png"))


def test_ground_level_places_the_ground_plane(tmp_path):
    box, ice = box_with_icicles()
    config = tiny_config()
    default = write_scenes(tmp_path / "default", box, ice, config)
    level = 0.0  # the box's underside: the icicles would reach below it
    files = write_scenes(tmp_path / "level", box, ice, config, ground_level=level)

    def ground_height(xml):
        m = np.array([float(x) for x in ET.parse(xml).getroot().find(
            "shape[@id='ground']/transform/matrix").get("value").split()]).reshape(4, 4)
        return m[1, 3]  # y is up

    assert ground_height(default.xml) == pytest.approx(ice.vertices[:, 1].min(), abs=1e-3)
    assert ground_height(files.xml) == pytest.approx(level, abs=1e-9)
    assert all(c.origin[1] > level for c in files.cameras)
    assert f"{level:.9g}" in files.pov.read_text().split("polygon {")[1].split("\n")[0]
    with pytest.raises(ValueError, match="ground_level"):
        write_scenes(tmp_path / "bad", box, ice, config, ground_level=float("nan"))


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
