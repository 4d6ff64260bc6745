"""ice_layer.usda: the job's ice composed over the USD asset's own file.

A 30 cm cube authored in centimetres, Z up, under nested transforms (a translated and turned
root, a scaled group, a translated mesh) runs once through ``icefarm run --no-render`` (its
stages only, about 2 s); the layer is opened as a DCC would, its ice compared with
``ice.ply`` taken back to the asset's frame independently of icefarm (the bounding box
centre ``prepare`` subtracts, and metersPerUnit), and the asset edited on disk and read in a
fresh Python process.
"""

from __future__ import annotations

import codecs
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from icefarm import artifacts
from icefarm.asset_io import read_asset
from icefarm.cli import main
from icefarm.errors import InputError
from icefarm.export.ice_layer import GROUP, write_ice_layer
from icefarm.jobdir import DONE, ICE, ICE_LAYER, ICE_USDC, SCENE_USDA, TIMINGS, check_done
from icefarm.mesh import prepare

CM = 0.01  # the asset's metersPerUnit
FAST = ["--set", "water.rays=300", "--set", "drips.count=4", "--set", "proxy.mode=never"]  # conftest.FAST
ROOT_MOVE = np.array([40.0, -25.0, 10.0])  # centimetres
# In a fresh interpreter: the composed stage's meshes in world space, and its composition errors.
READ_LAYER = textwrap.dedent("""
    import json, sys
    import numpy as np
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(sys.argv[1])
    out = {"errors": [str(e) for e in stage.GetCompositionErrors()]}
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.EarliestTime()))
            p = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64)
            out[str(prim.GetPath())] = (p @ m[:3, :3] + m[3, :3]).tolist()
    print(json.dumps(out))
""")


def write_cube_asset(path: Path, *, default: bool = True, second_root: bool = False) -> Path:
    """A 30 cm cube (15 units half-size after its group's scale 2) in centimetres, Z up:
    /Asset (translated, turned about Z) / Parts (scaled) / Cube (translated)."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, CM)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, "/Asset")
    root.AddTranslateOp().Set(Gf.Vec3d(100.0, 50.0, 20.0))
    root.AddRotateZOp().Set(30.0)
    UsdGeom.Xform.Define(stage, "/Asset/Parts").AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    box = trimesh.creation.box(extents=(15.0, 15.0, 15.0))
    cube = UsdGeom.Mesh.Define(stage, "/Asset/Parts/Cube")
    cube.CreatePointsAttr([Gf.Vec3f(*map(float, v)) for v in box.vertices])
    cube.CreateFaceVertexCountsAttr([3] * len(box.faces))
    cube.CreateFaceVertexIndicesAttr([int(i) for i in box.faces.ravel()])
    cube.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 7.5))
    if second_root:
        other = UsdGeom.Mesh.Define(stage, "/Other")
        other.CreatePointsAttr([Gf.Vec3f(*map(float, v + (0.0, 0.0, 200.0))) for v in box.vertices])
        other.CreateFaceVertexCountsAttr([3] * len(box.faces))
        other.CreateFaceVertexIndicesAttr([int(i) for i in box.faces.ravel()])
    if default:
        stage.SetDefaultPrim(root.GetPrim())
    stage.GetRootLayer().Save()
    return path


def world_meshes(layer: Path) -> dict:
    """`READ_LAYER` run on ``layer`` in a new Python process."""
    done = subprocess.run([sys.executable, "-c", READ_LAYER, str(layer)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return {k: (v if k == "errors" else np.array(v)) for k, v in json.loads(done.stdout).items()}


def expected_ice(asset: Path, ice_ply: Path) -> np.ndarray:
    """``ice.ply``'s points back in the asset's world space and units, as `prepare` made the
    job's frame: centimetres to meters, minus the bounding box's centre."""
    points = read_asset(asset).vertices
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    return trimesh.load(ice_ply, process=False).vertices / CM + centre


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """A job on the cube asset, its stages only (``--no-render``): the asset in ``asset/``,
    the job folder in ``job/``."""
    root = tmp_path_factory.mktemp("ice_layer")
    (root / "asset").mkdir()
    asset = write_cube_asset(root / "asset" / "cube.usda")
    result = CliRunner().invoke(main, ["run", str(asset), "-o", str(root / "job"), "--no-render", *FAST])
    assert result.exit_code == 0, result.output
    return asset, root / "job"


@pytest.mark.slow  # a job's stages (module fixture)
def test_the_layer_references_the_asset_by_a_relative_path_and_copies_none_of_it(job):
    from pxr import Sdf, Usd, UsdGeom

    asset, job_dir = job
    layer = job_dir / ICE_LAYER
    assert check_done(job_dir) is None and ICE_LAYER in json.loads((job_dir / DONE).read_text())["artifacts"]
    assert "ice_layer" in json.loads((job_dir / TIMINGS).read_text())["seconds"]
    text = Sdf.Layer.FindOrOpen(str(layer))
    assert list(text.GetPrimAtPath("/Asset").referenceList.prependedItems) == [Sdf.Reference("../asset/cube.usda")]
    assert text.GetPrimAtPath("/Asset/Parts") is None and "points" not in layer.read_text()
    stage = Usd.Stage.Open(str(layer))
    assert not stage.GetCompositionErrors()
    assert UsdGeom.GetStageMetersPerUnit(stage) == CM and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Asset")
    source = Usd.Stage.Open(str(asset))
    cube = UsdGeom.Mesh(stage.GetPrimAtPath("/Asset/Parts/Cube"))
    own = UsdGeom.Mesh(source.GetPrimAtPath("/Asset/Parts/Cube"))
    np.testing.assert_array_equal(np.array(cube.GetPointsAttr().Get()), np.array(own.GetPointsAttr().Get()))
    assert stage.GetPrimAtPath(f"/Asset/{GROUP}/Ice").IsA(UsdGeom.Mesh)


@pytest.mark.slow  # a job's stages (module fixture)
def test_the_ice_sits_on_the_cube_in_the_assets_units_as_ice_ply_has_it(job):
    asset, job_dir = job
    meshes = world_meshes(job_dir / ICE_LAYER)
    assert not meshes["errors"]
    ice, cube = meshes[f"/Asset/{GROUP}/Ice"], meshes["/Asset/Parts/Cube"]
    # within 10 µm (a thousandth of a centimetre): float32 meters near the origin
    np.testing.assert_allclose(ice, expected_ice(asset, job_dir / ICE), atol=1e-3)
    np.testing.assert_allclose(cube, read_asset(asset).vertices, atol=1e-4)  # the asset's own
    lo, hi = cube.min(axis=0), cube.max(axis=0)
    assert hi[2] - lo[2] == pytest.approx(30.0)  # 30 cm along Z, the asset's up axis
    # glaze over the top (Z up) and the sides; nothing far from the cube, nothing above its glaze
    assert hi[2] < ice[:, 2].max() < hi[2] + 5.0
    assert (ice.min(axis=0) > lo - 20.0).all() and (ice.max(axis=0) < hi + 20.0).all()


@pytest.mark.slow  # a job's stages (module fixture)
def test_the_ice_is_bound_to_the_glass_material(job):
    from pxr import Usd, UsdShade

    from icefarm.export.usd import ICE_OPACITY, OPENPBR_ID

    stage = Usd.Stage.Open(str(job[1] / ICE_LAYER))
    material = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(f"/Asset/{GROUP}/Ice")).ComputeBoundMaterial()[0]
    assert material.GetPath() == f"/Asset/{GROUP}/Looks/IceMaterial"
    glass = material.ComputeSurfaceSource("mtlx")[0]
    assert glass.GetIdAttr().Get() == OPENPBR_ID and glass.GetInput("transmission_weight").Get() == 1.0
    assert glass.GetInput("specular_ior").Get() == pytest.approx(1.31)
    preview = material.ComputeSurfaceSource()[0]
    assert preview.GetIdAttr().Get() == "UsdPreviewSurface"
    assert preview.GetInput("opacity").Get() == pytest.approx(ICE_OPACITY)


@pytest.mark.slow  # a job's stages (module fixture)
def test_the_layer_passes_usds_validators(job):
    """usdchecker's checks (UsdValidation), but for the OpenPBR node, which usd-core's Sdr
    registry lacks (it is built without MaterialX)."""
    validation = pytest.importorskip("pxr.UsdValidation")
    from pxr import Usd

    from icefarm.export.usd import OPENPBR_ID

    validators = validation.ValidationRegistry().GetOrLoadAllValidators()
    errors = validation.ValidationContext(validators).Validate(Usd.Stage.Open(str(job[1] / ICE_LAYER)))
    found = [e.GetMessage() for e in errors if not (e.GetName() == "MissingShaderIdInRegistry"
                                                    and OPENPBR_ID in e.GetMessage())]
    assert not found


@pytest.mark.slow  # a job's stages (module fixture), and a Python process to read the edit
def test_editing_the_asset_shows_through_and_its_root_carries_the_ice(job, tmp_path):
    from pxr import Gf, Usd, UsdGeom

    asset, job_dir = job
    before = world_meshes(job_dir / ICE_LAYER)
    original = asset.read_text()
    try:
        stage = Usd.Stage.Open(str(asset))
        ops = UsdGeom.Xformable(stage.GetPrimAtPath("/Asset")).GetOrderedXformOps()
        ops[0].Set(ops[0].Get() + Gf.Vec3d(*ROOT_MOVE))  # the root's translate
        cube = UsdGeom.Xformable(stage.GetPrimAtPath("/Asset/Parts/Cube")).GetOrderedXformOps()[0]
        cube.Set(Gf.Vec3d(0.0, 0.0, 20.0))  # the cube alone: 12.5 units up in its group, 25 cm
        stage.GetRootLayer().Save()
        del stage
        after = world_meshes(job_dir / ICE_LAYER)
        np.testing.assert_allclose(after[f"/Asset/{GROUP}/Ice"], before[f"/Asset/{GROUP}/Ice"] + ROOT_MOVE, atol=1e-3)
        np.testing.assert_allclose(after["/Asset/Parts/Cube"], before["/Asset/Parts/Cube"] + ROOT_MOVE + (0, 0, 25.0),
                                   atol=1e-3)
    finally:
        asset.write_text(original)


@pytest.mark.slow  # a job rendered at 48 x 36 pixels
def test_a_job_that_renders_writes_the_layer_over_the_ice_usdc_of_its_scene(job, tmp_path, sweep_kit):
    from pxr import Usd, UsdGeom

    asset, _ = job
    job_dir = tmp_path / "rendered"
    result = CliRunner().invoke(main, ["run", str(asset), "-o", str(job_dir), "--render",
                                       str(sweep_kit.tiny_render(tmp_path)), *FAST])
    assert result.exit_code == 0, result.output
    seconds = json.loads((job_dir / TIMINGS).read_text())["seconds"]
    order = list(seconds)  # after scene.usda, whose ice.usdc it references
    assert order[-1] == "ice_layer" and order.index("usd") < order.index("ice_layer")
    scene, layer = (Usd.Stage.Open(str(job_dir / name)) for name in (SCENE_USDA, ICE_LAYER))
    ice = UsdGeom.Mesh(layer.GetPrimAtPath(f"/Asset/{GROUP}/Ice"))
    assert ice.GetPrim().GetPrimStack()[-1].layer.realPath == str(job_dir / ICE_USDC)
    np.testing.assert_array_equal(np.array(ice.GetPointsAttr().Get()),
                                  np.array(UsdGeom.Mesh(scene.GetPrimAtPath("/World/Ice")).GetPointsAttr().Get()))


def fake_job(folder: Path, asset: Path) -> tuple[Path, trimesh.Trimesh, object]:
    """A job folder with only ``ice.ply``: a 4 cm box on top of the asset's object, in the
    job's frame (`prepare`'s)."""
    prepared = prepare(asset, None, (0.0, 0.0, -1.0))
    ice = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    ice.apply_translation((0.0, 0.0, prepared.mesh.vertices[:, 2].max() + 0.02))
    folder.mkdir(parents=True, exist_ok=True)
    artifacts.write_mesh(folder / ICE, ice)
    return folder, ice, prepared


def test_an_asset_with_several_root_prims_is_sublayered_and_a_stale_ice_usdc_replaced(tmp_path):
    """No default prim and two root prims: a reference would bring one; a sublayer keeps both,
    and the ice stands at the stage's root in world space. The layer written elsewhere than
    the job folder names the asset and ice.usdc by relative paths from there."""
    from pxr import Sdf, Usd, UsdGeom

    asset = write_cube_asset(tmp_path / "cube.usda", default=False, second_root=True)
    job_dir, ice, prepared = fake_job(tmp_path / "jobs" / "one", asset)
    (job_dir / ICE_USDC).write_text("an earlier job's")
    os.utime(job_dir / ICE_USDC, ns=(1, 1))  # older than ice.ply
    out = tmp_path / "layers" / "iced.usda"
    written = write_ice_layer(job_dir, asset, scale=prepared.scale, offset=prepared.offset, out=out)
    assert (written.arc, written.asset, written.group) == ("sublayer", "../cube.usda", f"/{GROUP}")
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert list(layer.subLayerPaths) == ["../cube.usda"]
    stage = Usd.Stage.Open(str(out))
    assert not stage.GetCompositionErrors()
    assert stage.GetPrimAtPath("/Other") and stage.GetPrimAtPath("/Asset/Parts/Cube")
    prim = stage.GetPrimAtPath(written.ice)
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(0))
    points = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(), dtype=np.float64)
    np.testing.assert_allclose(points @ m[:3, :3] + m[3, :3], (ice.vertices + prepared.offset) / prepared.scale,
                               atol=1e-4)


def test_the_ice_group_takes_a_free_name_and_the_asset_must_open_in_usd(tmp_path):
    from pxr import Usd, UsdGeom

    asset = write_cube_asset(tmp_path / "cube.usda")
    stage = Usd.Stage.Open(str(asset))
    UsdGeom.Xform.Define(stage, f"/Asset/{GROUP}")  # the asset has a prim by the group's name
    stage.GetRootLayer().Save()
    del stage
    job_dir, _, prepared = fake_job(tmp_path / "job", asset)
    written = write_ice_layer(job_dir, asset, scale=prepared.scale, offset=prepared.offset)
    assert (written.arc, written.group, written.asset) == ("reference", f"/Asset/{GROUP}_1", "../cube.usda")
    assert (job_dir / ICE_USDC).is_file()  # no render wrote it: the layer's writer did
    with pytest.raises(InputError, match="USD asset"):
        write_ice_layer(job_dir, job_dir / ICE, scale=1.0, offset=(0.0, 0.0, 0.0))
    marked = tmp_path / "marked.usda"  # icefarm reads it (asset_io), no USD tool does
    marked.write_bytes(codecs.BOM_UTF8 + asset.read_bytes())
    with pytest.raises(InputError, match="USD cannot open the asset"):
        write_ice_layer(job_dir, marked, scale=prepared.scale, offset=prepared.offset)


@pytest.mark.slow  # a job's stages
def test_an_asset_usd_cannot_open_still_makes_its_job_and_says_why_there_is_no_layer(tmp_path):
    asset = write_cube_asset(tmp_path / "cube.usda")
    marked = tmp_path / "marked.usda"  # icefarm reads it (asset_io), no USD tool does
    marked.write_bytes(codecs.BOM_UTF8 + asset.read_bytes())
    result = CliRunner().invoke(main, ["run", str(marked), "-o", str(tmp_path / "job"), "--no-render", *FAST])
    assert result.exit_code == 0, result.output
    assert "warning: no ice_layer.usda: " in result.stdout and "USD cannot open the asset" in result.stdout
    assert (tmp_path / "job" / "done.json").is_file() and not (tmp_path / "job" / "ice_layer.usda").exists()
