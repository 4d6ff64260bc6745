"""Export for DCCs: scene.usda read back by pxr in a fresh process, GLB and USDZ from the CLI.

One small rendered job (an icosphere with a proxy flow mesh, two views, a plastic object)
runs once for the module; the USD is read in a separate Python process, as a DCC would,
and compared with ice.ply, water.ply and the cameras Mitsuba loads from scene.xml.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from click.testing import CliRunner

from icefarm import params
from icefarm.cli import main
from icefarm.export.usd import crate_order, up_axis, write_job_usd, write_usdz
from icefarm.job.pipeline import JobSpec, run_job
from icefarm.jobdir import check_done
from icefarm.scene.config import ABSORPTION_PER_M, render_config_from_dict
from icefarm.scene.material import material_from_dict
from icefarm.scene.write import JobScene, write_scenes

PLASTIC = material_from_dict({"type": "plastic", "color": (0.6, 0.1, 0.1), "roughness": 0.09})

# Run in a fresh interpreter: everything a DCC sees of scene.usda, as JSON and .npy files.
READ_USD = textwrap.dedent("""
    import json, sys
    import numpy as np
    from pxr import Usd, UsdGeom, UsdShade, UsdLux
    stage = Usd.Stage.Open(sys.argv[1])
    out = sys.argv[2]
    facts = {"meters": UsdGeom.GetStageMetersPerUnit(stage), "up": UsdGeom.GetStageUpAxis(stage),
             "default": str(stage.GetDefaultPrim().GetPath()),
             "errors": [str(e) for e in stage.GetCompositionErrors()],
             "types": {str(p.GetPath()): str(p.GetTypeName()) for p in stage.Traverse()},
             "meshes": {}, "cameras": {}, "lights": {}}
    matrix = lambda prim: np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(0)).tolist()
    for prim in stage.Traverse():
        name = prim.GetName()
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            np.save(f"{out}/{name}_points.npy", np.array(mesh.GetPointsAttr().Get()))
            np.save(f"{out}/{name}_normals.npy", np.array(mesh.GetNormalsAttr().Get()))
            np.save(f"{out}/{name}_indices.npy", np.array(mesh.GetFaceVertexIndicesAttr().Get()))
            primvars = {}
            for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
                if pv.GetPrimvarName() in ("water", "supply", "crest"):
                    np.save(f"{out}/{name}_{pv.GetPrimvarName()}.npy", np.array(pv.Get()))
                    primvars[str(pv.GetPrimvarName())] = str(pv.GetInterpolation())
            material = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
            shader = material.ComputeSurfaceSource()[0]
            facts["meshes"][name] = {
                "extent": np.array(mesh.GetExtentAttr().Get()).tolist(),
                "faces": len(mesh.GetFaceVertexCountsAttr().Get()),
                "indices": np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3).tolist()[:1],
                "subdivision": str(mesh.GetSubdivisionSchemeAttr().Get()), "primvars": primvars,
                "material": str(material.GetPath()), "shader": str(shader.GetIdAttr().Get()),
                "inputs": {i.GetBaseName(): (list(i.Get()) if hasattr(i.Get(), "__len__") and not
                           isinstance(i.Get(), str) else i.Get()) for i in shader.GetInputs()}}
        elif prim.IsA(UsdGeom.Camera):
            camera = UsdGeom.Camera(prim)
            facts["cameras"][name] = {
                "matrix": matrix(prim), "focal": camera.GetFocalLengthAttr().Get(),
                "aperture": [camera.GetHorizontalApertureAttr().Get(), camera.GetVerticalApertureAttr().Get()],
                "clipping": list(camera.GetClippingRangeAttr().Get())}
        elif prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight):
            light = UsdLux.LightAPI(prim)
            entry = {"matrix": matrix(prim), "intensity": light.GetIntensityAttr().Get()}
            if prim.IsA(UsdLux.DomeLight):
                entry["texture"] = UsdLux.DomeLight(prim).GetTextureFileAttr().Get().resolvedPath
            facts["lights"][name] = entry
    with open(f"{out}/facts.json", "w") as f:
        json.dump(facts, f)
""")


def read_usd(scene, out):
    """What a fresh Python process reads from ``scene`` with pxr: facts and arrays in ``out``."""
    out.mkdir(exist_ok=True)
    done = subprocess.run([sys.executable, "-c", READ_USD, str(scene), str(out)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return {**json.loads((out / "facts.json").read_text()), "dir": out}


def glb_json(path):
    """The JSON chunk of a GLB file (header, then chunk length and type, then the chunk)."""
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON"
    return json.loads(data[20:20 + length])


def mitsuba_sensors(xml):
    """``(to_world 4x4, x fov in degrees)`` of each sensor Mitsuba loads from ``xml``."""
    import mitsuba as mi

    from icefarm.scene.variants import pick_variant

    mi.set_variant(pick_variant("scalar_rgb"))
    scene = mi.load_file(str(xml))
    return [(np.array(s.world_transform().matrix), float(mi.traverse(s)["x_fov"][0])
             if hasattr(mi.traverse(s)["x_fov"], "__len__") else float(mi.traverse(s)["x_fov"]))
            for s in scene.sensors()]


def assert_camera_is_mitsubas(usd_camera, to_world, fov_x):
    """USD cameras look down local -Z with +X right; Mitsuba's down +Z with +X left."""
    usd = np.array(usd_camera["matrix"]).T  # USD's row vectors to column vectors
    np.testing.assert_allclose(usd[:3, 3], to_world[:3, 3], atol=1e-5)
    np.testing.assert_allclose(usd[:3, :3], to_world[:3, :3] @ np.diag([-1.0, 1.0, -1.0]), atol=1e-5)
    h, v = usd_camera["aperture"]
    assert np.degrees(2 * np.arctan(h / 2 / usd_camera["focal"])) == pytest.approx(fov_x, abs=1e-3)


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """A rendered icosphere job: proxy flow mesh (its vertices are not the object's), glaze,
    eight icicles, a rough-ice config with the main and the ice view, a plastic object."""
    root = tmp_path_factory.mktemp("export")
    trimesh.creation.icosphere(subdivisions=4, radius=0.15).export(root / "sphere.ply")
    config = root / "tiny.yaml"
    config.write_text("resolution: [40, 30]\nspp: 2\nmax_depth: 4\nviews: [three_quarter, ice]\n"
                      "ice: {roughness: 0.04}\n")
    p = params.resolve({"water.rays": 2000, "drips.count": 8, "drips.drip_limit": 80, "proxy.mode": "always"})
    spec = JobSpec("sphere", str(root / "sphere.ply"), 0.3, p, seed=3, render=str(config), material=PLASTIC)
    outcome = run_job(spec, root / "job")
    assert outcome.status == "done", outcome.error
    return root / "job"


@pytest.fixture(scope="module")
def usd(job, tmp_path_factory):
    return read_usd(job / "scene.usda", tmp_path_factory.mktemp("usd"))


def _tiny_job(root: Path):
    trimesh.creation.icosphere(subdivisions=3, radius=0.15).export(root / "sphere.ply")
    config = root / "tiny.yaml"
    config.write_text("resolution: [32, 24]\nspp: 1\nmax_depth: 4\nviews: [three_quarter]\n")
    p = params.resolve({"water.rays": 1000, "drips.count": 4, "drips.drip_limit": 80})
    return JobSpec("sphere", str(root / "sphere.ply"), 0.3, p, seed=1, render=str(config))


@pytest.mark.slow  # two rendered jobs
def test_the_usd_export_runs_beside_the_render_and_fails_its_own_step(tmp_path, monkeypatch):
    import ast
    import threading

    import icefarm.export.usd as usd_module

    threads, parsers = [], set()
    real, real_parse = usd_module.write_usd, ast.parse

    def watched(*args, **kwargs):
        threads.append(threading.current_thread())
        return real(*args, **kwargs)

    def parse(*args, **kwargs):
        parsers.add(threading.current_thread())
        return real_parse(*args, **kwargs)

    monkeypatch.setattr(usd_module, "write_usd", watched)
    # Python 3.11's ast.parse fails when two threads parse at once (CPython gh-106905): only the
    # job's own thread may parse, though the PLY reader and Mitsuba's integrators both do.
    monkeypatch.setattr(ast, "parse", parse)
    outcome = run_job(_tiny_job(tmp_path), tmp_path / "job")
    assert outcome.status == "done", outcome.error
    assert len(threads) == 1 and threads[0] is not threading.main_thread()  # the render's writer thread
    assert parsers == {threading.main_thread()}
    timings = json.loads((tmp_path / "job" / "timings.json").read_text())
    assert timings["usd_write_seconds"] > 0 and "usd" in timings["seconds"]

    def broken(*args, **kwargs):
        raise OSError("the disk is full")

    for name in ("write_usd", "read_usd_inputs"):  # the writing fails, or the reading
        monkeypatch.setattr(usd_module, name, broken)
        failed = run_job(_tiny_job(tmp_path), tmp_path / name)
        assert failed.status == "failed" and failed.failed_stage == "usd" and "the disk is full" in (failed.error or "")
        assert (tmp_path / name / "render.png").is_file() and not (tmp_path / name / "done.json").exists()


@pytest.mark.slow  # two rendered jobs
def test_the_measures_run_beside_the_render_and_fail_their_own_step(tmp_path, monkeypatch):
    import threading

    import icefarm.stages as stages
    from icefarm.job import JobInputs, run_graph, step
    from icefarm.job.pipeline import load_object, meshing_params

    threads, real = [], stages.measure_icicles

    def watched(*args, **kwargs):
        threads.append(threading.current_thread())
        return real(*args, **kwargs)

    monkeypatch.setattr(stages, "measure_icicles", watched)
    spec = _tiny_job(tmp_path)
    outcome = run_job(spec, tmp_path / "job")
    assert outcome.status == "done", outcome.error
    assert len(threads) == 1 and threads[0] is not threading.main_thread()
    timings = json.loads((tmp_path / "job" / "timings.json").read_text())
    assert timings["measure_beside_seconds"] > 0 and "measure" in timings["seconds"]
    assert list(timings["seconds"]).index("measure") > list(timings["seconds"]).index("render")
    # the same figures as the graph measures on the same ice, one step after another
    p, _ = meshing_params(spec)
    inputs = JobInputs(load_object(spec), p, spec.seed)
    expected = step("measure").figures(inputs, run_graph(inputs, measuring=True))
    assert expected and json.loads(json.dumps(expected)) == {k: timings[k] for k in expected}

    def broken(*args, **kwargs):
        raise OSError("no memory left")

    # a farm worker with one core measures first, in its own thread
    threads.clear()
    assert run_job(spec, tmp_path / "in_turn", measure_beside=False).status == "done"
    assert threads == [threading.main_thread()]
    in_turn = json.loads((tmp_path / "in_turn" / "timings.json").read_text())
    assert "measure_beside_seconds" not in in_turn and {k: in_turn[k] for k in expected} == {
        k: timings[k] for k in expected}
    assert list(in_turn["seconds"]).index("measure") < list(in_turn["seconds"]).index("render")

    monkeypatch.setattr(stages, "measure_icicles", broken)
    failed = run_job(_tiny_job(tmp_path), tmp_path / "broken")
    assert failed.status == "failed" and failed.failed_stage == "measure" and "no memory left" in (failed.error or "")
    assert (tmp_path / "broken" / "render.png").is_file() and not (tmp_path / "broken" / "done.json").exists()


@pytest.mark.slow  # two rendered jobs
def test_a_farm_worker_with_one_core_measures_before_its_render(tmp_path):
    """On a worker whose share is one core the render would only wait for the measures."""
    import drjit as dr

    from icefarm.farm.task import Task, execute

    spec = _tiny_job(tmp_path)
    pool = dr.thread_count()
    try:
        for threads in (1, 2):
            job_dir = tmp_path / f"threads{threads}"
            task = Task(spec, f"j{threads}", "sphere", str(job_dir), None, None, str(tmp_path / "running"), threads)
            (tmp_path / "running").mkdir(exist_ok=True)
            outcome, _ = execute(task)
            assert outcome.status == "done", outcome.error
            timings = json.loads((job_dir / "timings.json").read_text())
            order = list(timings["seconds"])
            assert ("measure_beside_seconds" in timings) is (threads > 1)
            assert (order.index("measure") > order.index("render")) is (threads > 1)
    finally:
        dr.set_thread_count(pool)


def test_up_axis_follows_gravity_to_the_nearest_of_y_and_z():
    assert up_axis((0, -1, 0)) == "Y" and up_axis((0, 0, -1)) == "Z"
    assert up_axis((0.2, -0.9, 0.3)) == "Y" and up_axis((0.3, 0.2, -0.9)) == "Z"
    assert up_axis((0, 1, 0)) == "Y" and up_axis((-1, 0, 0)) == "Y"


@pytest.mark.slow  # a rendered job (module fixture)
def test_job_writes_scene_usda_as_a_timed_step_listed_in_done_json(job):
    done = json.loads((job / "done.json").read_text())
    assert {"scene.usda", "object.usdc", "ice.usdc"} <= set(done["artifacts"])
    assert "usd" in done["seconds"] and check_done(job) is None
    assert (job / "ice.usdc").read_bytes()[:8] == b"PXR-USDC"  # binary crate layers
    assert not list(job.glob(".*.usd*")), "no temporary layer is left behind"


@pytest.mark.slow  # a rendered job (module fixture)
def test_stage_is_in_meters_y_up_with_the_expected_prims(usd):
    assert usd["meters"] == 1.0 and usd["up"] == "Y" and usd["default"] == "/World"
    assert usd["errors"] == []
    types = usd["types"]
    assert types["/World/Object"] == types["/World/Ice"] == "Mesh"
    assert types["/World/Cameras/three_quarter"] == types["/World/Cameras/ice"] == "Camera"
    assert types["/World/Lights/Sun"] == "DistantLight" and types["/World/Lights/Sky"] == "DomeLight"
    assert types["/World/Looks/IceMaterial"] == "Material"
    assert types["/World/Looks/IceMaterial/PreviewSurface"] == "Shader"


@pytest.mark.slow  # a rendered job (module fixture)
def test_meshes_hold_the_plys_points_with_extents_and_normals(job, usd):
    out = usd["dir"]
    for name, ply in (("Ice", "ice.ply"), ("Object", "object.ply")):
        mesh = trimesh.load(job / ply, process=False)
        points = np.load(out / f"{name}_points.npy")
        np.testing.assert_allclose(points, np.asarray(mesh.vertices, dtype=np.float32), rtol=0, atol=1e-7)
        facts = usd["meshes"][name]
        assert facts["faces"] == len(mesh.faces) and facts["subdivision"] == "none"
        np.testing.assert_allclose(facts["extent"], [points.min(axis=0), points.max(axis=0)], atol=1e-7)
        # the same triangles, whatever their order (ice.usdc lists them shuffled: `crate_order`)
        triangles = [np.sort(np.asarray(f).reshape(-1, 3), axis=1) for f in (np.load(out / f"{name}_indices.npy"),
                                                                           mesh.faces)]
        usd_tris, ply_tris = (t[np.lexsort(t.T[::-1])] for t in triangles)
        assert np.array_equal(usd_tris, ply_tris)
        normals = np.load(out / f"{name}_normals.npy")
        assert normals.shape == points.shape
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)
    # Outward: the ice's lowest point (an icicle's tip) has a normal pointing down.
    ice_points, ice_normals = np.load(out / "Ice_points.npy"), np.load(out / "Ice_normals.npy")
    assert ice_normals[np.argmin(ice_points[:, 1]), 1] < -0.5


@pytest.mark.slow  # a rendered job (module fixture)
def test_ice_carries_its_milky_ripple_bands_per_vertex(job, usd):
    from icefarm.artifacts import read_ice_mesh
    from icefarm.jobdir import ICE_BANDS

    assert usd["meshes"]["Ice"]["primvars"] == {"crest": "vertex"}
    bands = read_ice_mesh(job / "ice.ply").vertex_attributes[ICE_BANDS]
    crest = np.load(usd["dir"] / "Ice_crest.npy")
    np.testing.assert_array_equal(crest, bands)  # the ice's vertices keep ice.ply's order
    assert crest.max() > 0.5 and crest.min() == 0.0


@pytest.mark.slow  # a rendered job (module fixture)
def test_ice_material_is_bound_with_ior_transmission_roughness_and_tint(usd):
    ice = usd["meshes"]["Ice"]
    assert ice["material"] == "/World/Looks/IceMaterial" and ice["shader"] == "UsdPreviewSurface"
    inputs = ice["inputs"]
    assert inputs["ior"] == pytest.approx(1.31)
    assert inputs["opacity"] <= 0.2 and inputs["opacityMode"] == "transparent"
    assert inputs["roughness"] == pytest.approx(0.2)  # sqrt of the config's GGX alpha 0.04
    absorption = np.asarray(ABSORPTION_PER_M)  # tiny.yaml keeps the built-in absorption
    np.testing.assert_allclose(inputs["diffuseColor"], np.exp(-absorption * 0.1), atol=1e-4)


@pytest.mark.slow  # a rendered job (module fixture)
def test_object_has_its_manifest_material_and_the_water_of_stage_1(job, usd):
    obj = usd["meshes"]["Object"]
    assert obj["material"] == "/World/Looks/ObjectMaterial"
    np.testing.assert_allclose(obj["inputs"]["diffuseColor"], [0.6, 0.1, 0.1], atol=1e-6)
    assert obj["inputs"]["roughness"] == pytest.approx(0.3)
    assert obj["primvars"] == {"water": "vertex", "supply": "vertex"}
    out = usd["dir"]
    points = np.load(out / "Object_points.npy")
    water, supply = np.load(out / "Object_water.npy"), np.load(out / "Object_supply.npy")
    # The proxy's vertices are not the object's: each takes its nearest flow vertex's values
    # (brute force here, a KD-tree in icefarm).
    flow = trimesh.load(job / "water.ply", process=False)
    data = flow.metadata["_ply_raw"]["vertex"]["data"]
    assert len(flow.vertices) != len(points)
    nearest = np.argmin(((points[:, None, :] - np.asarray(flow.vertices)[None]) ** 2).sum(axis=2), axis=1)
    np.testing.assert_allclose(water, data["water"][nearest], rtol=1e-6)
    np.testing.assert_array_equal(supply, data["supply"][nearest].astype(int))
    assert water.max() > 0 and supply.any()


@pytest.mark.slow  # a rendered job (module fixture)
def test_cameras_are_the_ones_mitsuba_rendered(job, usd):
    sensors = mitsuba_sensors(job / "scene.xml")
    names = [v["name"] for v in json.loads((job / "views.json").read_text())]
    assert names == ["three_quarter", "ice"] and len(sensors) == 2
    for name, (to_world, fov_x) in zip(names, sensors):
        camera = usd["cameras"][name]
        assert_camera_is_mitsubas(camera, to_world, fov_x)
        assert camera["aperture"][0] / camera["aperture"][1] == pytest.approx(40 / 30)


@pytest.mark.slow  # a rendered job (module fixture)
def test_sun_and_sky_are_the_renders(job, usd):
    root = ET.parse(job / "scene.xml").getroot()
    emitters = {e.get("type"): e for e in root.iter("emitter")}
    direction = np.array(emitters["directional"].find("vector").get("value").split(","), dtype=float)
    sun = np.array(usd["lights"]["Sun"]["matrix"])
    np.testing.assert_allclose(-sun[2, :3], direction, atol=1e-6)  # a distant light shines along -Z
    assert usd["lights"]["Sun"]["intensity"] == pytest.approx(3.0)
    sky = usd["lights"]["Sky"]
    assert sky["texture"] == str(job / emitters["envmap"].find("string").get("value"))
    frame = np.array(emitters["envmap"].find("transform/matrix").get("value").split(), dtype=float)
    np.testing.assert_allclose(np.array(sky["matrix"]).T, frame.reshape(4, 4), atol=1e-9)


@pytest.mark.slow  # a rendered job (module fixture)
def test_glb_export_has_the_ice_with_transmission_and_ior(job):
    out = job.parent / "scene.glb"
    result = CliRunner().invoke(main, ["export", str(job), "--format", "glb", "-o", str(out)])
    assert result.exit_code == 0, result.output
    loaded = trimesh.load(out)
    assert len(loaded.geometry["ice"].faces) == len(trimesh.load(job / "ice.ply", process=False).faces)
    assert len(loaded.geometry["object"].faces) == len(trimesh.load(job / "object.ply", process=False).faces)
    tree = glb_json(out)
    ice = next(m for m in tree["materials"] if m["name"] == "ice")
    assert ice["extensions"]["KHR_materials_transmission"]["transmissionFactor"] == 1.0
    assert ice["extensions"]["KHR_materials_ior"]["ior"] == pytest.approx(1.31)
    assert ice["pbrMetallicRoughness"]["roughnessFactor"] == pytest.approx(0.2)
    assert ice["extensions"]["KHR_materials_volume"]["attenuationDistance"] > 0
    assert {"KHR_materials_transmission", "KHR_materials_ior"} <= set(tree["extensionsUsed"])
    obj = next(m for m in tree["materials"] if m["name"] == "object")
    assert obj["pbrMetallicRoughness"]["baseColorFactor"] == pytest.approx([0.6, 0.1, 0.1, 1.0])


@pytest.mark.slow  # a rendered job (module fixture)
def test_glb_is_a_complete_scene_with_ground_cameras_and_sun(job):
    """The ground the render stood on, the rendered cameras and the sun: what a viewer needs."""
    from icefarm.scene import read_scene_spec
    from icefarm.scene.camera import world_frame

    out = job.parent / "complete.glb"
    assert CliRunner().invoke(main, ["export", str(job), "--format", "glb", "-o", str(out)]).exit_code == 0
    tree = glb_json(out)
    assert tree["asset"]["generator"].startswith("icefarm")
    assert all(view.get("target") in (34962, 34963) for view in tree["bufferViews"])
    nodes = {n["name"]: n for n in tree["nodes"]}
    assert {"object", "ice", "ground", "camera_three_quarter", "camera_ice", "sun"} <= set(nodes)
    scene = tree["scenes"][tree.get("scene", 0)]["nodes"]
    assert all(tree["nodes"].index(nodes[k]) in scene for k in ("ground", "camera_three_quarter", "sun"))
    spec = read_scene_spec(job)
    frame = world_frame(spec.gravity)

    def turned(quaternion, v):
        x, y, z, w = quaternion
        m = trimesh.transformations.quaternion_matrix([w, x, y, z])[:3, :3]
        return m @ np.asarray(v, dtype=float)

    for camera, view in zip(spec.cameras, spec.views):
        node = nodes[f"camera_{view.name}"]
        np.testing.assert_allclose(node["translation"], frame @ camera.origin, atol=1e-6)
        np.testing.assert_allclose(turned(node["rotation"], [0, 0, -1]), frame @ camera.forward, atol=1e-6)
        assert turned(node["rotation"], [0, 1, 0])[1] > 0  # upright: glTF's +Y is minus gravity
        assert tree["cameras"][node["camera"]]["perspective"]["yfov"] == pytest.approx(np.radians(camera.fov_y))
    sun = nodes["sun"]
    light = tree["extensions"]["KHR_lights_punctual"]["lights"][sun["extensions"]["KHR_lights_punctual"]["light"]]
    assert light["type"] == "directional" and light["intensity"] > 0
    np.testing.assert_allclose(turned(sun["rotation"], [0, 0, 1]), frame @ spec.sun.direction, atol=1e-6)
    ground = trimesh.load(out).geometry["ground"]
    assert len(ground.faces) == 2 and np.ptp(ground.vertices[:, 1]) < 1e-6  # level in glTF's Y-up
    assert ground.vertices[:, 1].max() <= trimesh.load(out).geometry["object"].vertices[:, 1].min() + 1e-3


@pytest.mark.slow  # a rendered job (module fixture)
def test_usd_scene_has_the_rendered_ground_with_a_matte_material(job):
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(job / "scene.usda"))
    ground = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Ground"))
    points = np.asarray(ground.GetPointsAttr().Get())
    assert points.shape == (4, 3) and np.ptp(points[:, 1]) < 1e-6  # Y up: level
    assert list(ground.GetFaceVertexCountsAttr().Get()) == [3, 3]
    material = UsdShade.MaterialBindingAPI(ground.GetPrim()).ComputeBoundMaterial()[0]
    shader = material.ComputeSurfaceSource()[0]
    assert shader.GetInput("roughness").Get() == 1.0
    assert tuple(shader.GetInput("specularColor").Get()) == (0.0, 0.0, 0.0)


@pytest.mark.slow  # a rendered job (module fixture)
def test_usdz_export_packs_scene_meshes_and_sky(job, tmp_path):
    import zipfile

    out = tmp_path / "scene.usdz"
    result = CliRunner().invoke(main, ["export", str(job), "--format", "usdz", "-o", str(out)])
    assert result.exit_code == 0, result.output
    names = zipfile.ZipFile(out).namelist()
    assert names[0] == "scene.usda" and {"object.usdc", "ice.usdc"} <= set(names)
    assert any(n.endswith(".exr") for n in names)
    assert read_usd(out, tmp_path / "facts")["types"]["/World/Ice"] == "Mesh"


@pytest.mark.parametrize("fmt", ["glb", "usdz"])
def test_export_of_a_folder_that_never_rendered_is_one_clear_line(tmp_path, fmt):
    result = CliRunner().invoke(main, ["export", str(tmp_path), "--format", fmt])
    assert result.exit_code == 2
    message = result.output.strip()
    assert "\n" not in message and "ice.ply" in message and "run" in message
    assert "Traceback" not in result.output


@pytest.mark.slow  # starts a process (read_usd: pxr in a fresh Python)
def test_z_up_gravity_gives_a_z_up_stage_and_a_y_up_glb(tmp_path):
    """A job folder written by `write_scenes` with gravity along -Z, exported without a
    done.json: the material is passed in, and the usdz is made from a fresh scene.usda."""
    box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    ice = trimesh.creation.cone(radius=0.01, height=0.08, sections=16)
    ice.apply_translation((0.0, 0.0, -0.13))
    ice.invert()  # inward winding: exported wound outwards
    config = render_config_from_dict({"resolution": [40, 30], "spp": 2, "max_depth": 4})
    job = tmp_path / "job"
    write_scenes(job, JobScene(box, ice, gravity=(0.0, 0.0, -1.0)), config)
    (job / "params.yaml").write_text(yaml.safe_dump({"water": {"gravity": [0.0, 0.0, -1.0]}}))
    written = write_job_usd(job, material=PLASTIC)
    assert written.up_axis == "Z"
    usd = read_usd(written.scene, tmp_path / "facts")
    assert usd["up"] == "Z" and usd["meters"] == 1.0
    (to_world, fov_x), = mitsuba_sensors(job / "scene.xml")
    assert_camera_is_mitsubas(usd["cameras"]["three_quarter"], to_world, fov_x)
    points, normals = np.load(usd["dir"] / "Ice_points.npy"), np.load(usd["dir"] / "Ice_normals.npy")
    assert normals[np.argmin(points[:, 2]), 2] < -0.5  # the tip's normal points down, the way gravity does
    # glTF is +Y up: the root turns minus gravity (+Z here) to +Y.
    from icefarm.export.gltf import write_glb

    (job / "done.json").write_text(json.dumps({"object_material": PLASTIC.to_dict()}))
    tree = glb_json(write_glb(job, tmp_path / "z.glb"))
    node = next(n for n in tree["nodes"] if n.get("name") == "ice")
    turn = np.array(node["matrix"]).reshape(4, 4).T  # glTF matrices are column-major
    np.testing.assert_allclose(turn[:3, :3] @ [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], atol=1e-12)
    (job / "scene.usda").unlink()
    packed = write_usdz(job, tmp_path / "z.usdz")
    assert read_usd(packed, tmp_path / "facts_z")["up"] == "Z"
    assert not (job / "scene.usda").exists(), "a usdz of an older job leaves the job as it was"


@pytest.mark.slow  # a rendered job (module fixture)
def test_ice_carries_a_materialx_openpbr_glass_and_the_object_is_double_sided(job):
    """Readers of MaterialX (usdview, Houdini, Maya, Omniverse) get glass, not a faint shell."""
    from pxr import Usd, UsdGeom, UsdShade

    from icefarm.export.looks import TINT_DISTANCE_M
    from icefarm.export.usd import OPENPBR_ID

    stage = Usd.Stage.Open(str(job / "scene.usda"))
    material = UsdShade.Material(stage.GetPrimAtPath("/World/Looks/IceMaterial"))
    shader = material.ComputeSurfaceSource("mtlx")[0]
    assert shader and shader.GetIdAttr().Get() == OPENPBR_ID
    value = lambda name: shader.GetInput(name).Get()  # noqa: E731
    assert value("transmission_weight") == 1.0 and value("base_weight") == 0.0
    assert value("specular_ior") == pytest.approx(1.31) and value("geometry_thin_walled") is False
    assert value("transmission_depth") == pytest.approx(TINT_DISTANCE_M)
    np.testing.assert_allclose(list(value("transmission_color")), np.exp(-np.asarray(ABSORPTION_PER_M) * 0.1),
                               atol=1e-4)
    assert 0.0 <= value("transmission_scatter")[0] <= 1.0
    # the preview surface stays for readers without MaterialX
    assert material.ComputeSurfaceSource()[0].GetIdAttr().Get() == "UsdPreviewSurface"
    obj = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Object"))
    assert obj.GetDoubleSidedAttr().Get() is True


BLENDER_PYTHON = Path(__file__).resolve().parents[1] / ".venv-blender" / "bin" / "python"
BLENDER_IMPORT = textwrap.dedent("""
    import importlib.util, json, sys
    import bpy
    if sys.argv[3] == "hook":  # the hook loaded from its file, as Blender's script folders would
        spec = importlib.util.spec_from_file_location("blender_usd_hook", sys.argv[2])
        blender_usd_hook = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(blender_usd_hook)
        blender_usd_hook.register()
    bpy.ops.wm.usd_import(filepath=sys.argv[1])
    out = {}
    for m in bpy.data.materials:
        bsdf = next((n for n in m.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None) if m.node_tree else None
        if bsdf is not None:
            out[m.name] = {k: float(bsdf.inputs[k].default_value) for k in ("Transmission Weight", "IOR", "Alpha")}
    print("RESULT " + json.dumps(out))
""")


@pytest.mark.slow
@pytest.mark.skipif(not BLENDER_PYTHON.is_file(), reason="no .venv-blender with bpy (.ci/setup.sh makes it)")
def test_blender_imports_the_ice_as_glass_with_the_hook_and_as_a_shell_without(job):
    """Blender 5.0 (bpy) importing scene.usda: its importer alone reads the preview surface (a
    faint shell); with icefarm/dcc/blender_usd_hook.py registered the ice is glass."""
    from icefarm import dcc

    def materials(mode):
        done = subprocess.run([str(BLENDER_PYTHON), "-c", BLENDER_IMPORT, str(job / "scene.usda"),
                               str(Path(dcc.__file__).parent / "blender_usd_hook.py"), mode],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
        return json.loads(line[len("RESULT "):])

    plain = materials("plain")["IceMaterial"]
    assert plain["Transmission Weight"] == 0.0 and plain["Alpha"] == pytest.approx(0.1)
    hooked = materials("hook")
    assert hooked["IceMaterial"]["Transmission Weight"] == 1.0 and hooked["IceMaterial"]["IOR"] == pytest.approx(1.31)
    assert hooked["IceMaterial"]["Alpha"] == 1.0
    assert hooked["ObjectMaterial"]["Transmission Weight"] == 0.0  # the object is left alone


@pytest.mark.slow  # a rendered job (module fixture)
def test_scene_json_describes_what_scene_xml_renders(job, tmp_path):
    """The exporters read scene.json; it says what scene.xml says (the XML is read only
    for jobs from before scene.json)."""
    import shutil

    from icefarm.scene import read_scene_spec

    spec = json.loads((job / "scene.json").read_text())  # a rendered job has scene.json, listed as an artifact
    assert "scene.json" in json.loads((job / "done.json").read_text())["artifacts"]
    assert spec["version"] == 2 and spec["object"]["file"] == "object.ply" and spec["ice"]["file"] == "ice.ply"
    old = tmp_path / "old"
    shutil.copytree(job, old)
    (old / "scene.json").unlink()
    a, b = read_scene_spec(job), read_scene_spec(old)
    assert [v.name for v in a.views] == [v.name for v in b.views] and a.resolution == b.resolution
    for ca, cb in zip(a.cameras, b.cameras, strict=True):
        for name in ("origin", "target", "up"):
            np.testing.assert_allclose(getattr(ca, name), getattr(cb, name), atol=1e-6)
        assert ca.fov_x == pytest.approx(cb.fov_x, abs=1e-6) and ca.far == pytest.approx(cb.far, rel=1e-6)
    np.testing.assert_allclose(a.sun.direction, b.sun.direction, atol=1e-6)
    np.testing.assert_allclose(a.sun.irradiance, b.sun.irradiance, rtol=1e-6)
    assert a.sky.file == b.sky.file and a.sky.scale == pytest.approx(b.sky.scale)
    np.testing.assert_allclose(a.frame, b.frame, atol=1e-9)
    np.testing.assert_allclose(a.ground.corners, b.ground.corners, atol=1e-6)
    np.testing.assert_allclose(a.ground.color, b.ground.color, atol=1e-6)
    assert a.ice.ior == pytest.approx(b.ice.ior) and a.ice.roughness == pytest.approx(b.ice.roughness)
    assert a.ice_flip == b.ice_flip and a.ice.tint == pytest.approx(b.ice.tint)
    np.testing.assert_allclose(a.ice.absorption, b.ice.absorption, rtol=1e-6)
    assert a.ice.scattering == pytest.approx(b.ice.scattering, rel=1e-6)
    assert a.ice.shimmer == pytest.approx(b.ice.shimmer) and a.ice.shimmer > 0  # the job's ice is impure
    np.testing.assert_allclose(a.gravity, b.gravity)
    assert a.material == b.material


@pytest.mark.parametrize("flip", [False, True])
def test_the_ice_surface_takes_the_normals_the_render_computed(flip):
    """USD's ice normals can come from the scene's writer (`SceneFiles.ice_normals`, for the
    unflipped faces): the same as computing them again, flipped with the faces."""
    from icefarm.export.meshes import ice_surface
    from icefarm.scene.geometry import smooth_normals

    mesh = trimesh.creation.icosphere(subdivisions=3)
    faces = mesh.faces[:, ::-1] if flip else mesh.faces  # inward-wound ice, as SceneSpec.ice_flip says
    computed = ice_surface(mesh.vertices, faces, flip)
    given = ice_surface(mesh.vertices, faces, flip, normals=smooth_normals(mesh.vertices, faces))
    np.testing.assert_array_equal(given.faces, computed.faces)
    np.testing.assert_allclose(given.normals, computed.normals, atol=1e-6)
    assert (np.einsum("ij,ij->i", given.normals, mesh.vertices) > 0).all()  # outwards
    wrong = ice_surface(mesh.vertices, faces, flip, normals=np.zeros((3, 3)))  # not this mesh's: computed
    np.testing.assert_allclose(wrong.normals, computed.normals)


def test_crate_order_is_one_fixed_shuffle_of_every_face():
    order = crate_order(1000)
    assert np.array_equal(np.sort(order), np.arange(1000)) and np.array_equal(order, crate_order(1000))
    assert (np.diff(order) == 1).mean() < 0.01  # not runs kept in order: those save as slowly as none shuffled
