"""What a user hands icefarm reads as they meant it: numbers in any notation, text with a
byte-order mark, compressed glTF, reused and full and read-only folders."""

from __future__ import annotations

import base64
import codecs
import dataclasses
import errno
import json
import os
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from icefarm import params
from icefarm.asset_io import asset_gravity, read_asset
from icefarm.errors import InputError
from icefarm.farm.manifest import load_manifest
from icefarm.farm.points import parse_set
from icefarm.job.cache import StageCache, write_policy
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.jobdir import check_done
from icefarm.yaml_io import load_yaml


# ---------------------------------------------------------------- numbers
@pytest.mark.parametrize("text, value", [("5e-2", 0.05), ("1E3", 1000.0), ("-2.5e+3", -2500.0),
                                         ("1.5e3", 1500.0), (".5", 0.5), ("3", 3), ("1_000", 1000)])
def test_numbers_in_any_notation_read_as_numbers(text, value):
    assert load_yaml(text) == value and type(load_yaml(text)) is type(value)


@pytest.mark.parametrize("text", ["1e", "e5", "1e-2x", "0.1.2", "tubes"])
def test_text_that_only_looks_like_a_number_stays_text(text):
    assert load_yaml(text) == text


def test_set_and_manifest_take_scientific_notation(tmp_path, ball):
    assert parse_set("drips.spacing=5e-2") == ("drips.spacing", (0.05,))
    assert parse_set("drips.spacing=5e-2,1e-1") == ("drips.spacing", (0.05, 0.1))
    path = tmp_path / "m.yaml"
    path.write_text(f"name: t\nrender: null\ndefaults: {{drips.spacing: 5e-2}}\n"
                    f"objects:\n  - {{id: ball, mesh: {ball.name}, size_m: 3e-1}}\n")
    m = load_manifest(path)
    assert m.defaults == {"drips.spacing": 0.05} and m.objects[0].size_m == 0.3


# ---------------------------------------------------------------- text with a byte-order mark
# Two triangles; the first vertex is the one a mark glued to the first line would lose, and the
# last is unused, so a shifted index would load silently.
OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 5 5 5\nf 1 2 3\nf 1 2 4\n"
TEXT_MESHES = {
    "t.obj": OBJ,
    "t.off": "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n",
    "t.stl": "solid t\n" + "".join(f"facet normal 0 0 1\nouter loop\n{v}endloop\nendfacet\n" for v in (
        "vertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n", "vertex 0 0 0\nvertex 1 0 0\nvertex 0 0 1\n")) + "endsolid t\n",
    "t.ply": ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
              "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n"),
    "t.usda": ('#usda 1.0\n(\n    metersPerUnit = 0.5\n    upAxis = "Z"\n)\ndef Mesh "m"\n{\n'
               "    int[] faceVertexCounts = [3, 3]\n    int[] faceVertexIndices = [0, 1, 2, 0, 1, 3]\n"
               "    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]\n}\n"),
}
TWO_TRIANGLES = {(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)}


def corners(asset) -> set:
    """The corners of every face, as a set of points (formats number vertices differently)."""
    return {tuple(float(x) for x in p) for p in asset.vertices[asset.faces].reshape(-1, 3)}


@pytest.mark.parametrize("name", sorted(TEXT_MESHES))
@pytest.mark.parametrize("mark, codec", [(codecs.BOM_UTF8, "utf-8"), (codecs.BOM_UTF16_LE, "utf-16-le")])
def test_text_meshes_with_a_byte_order_mark_read_as_without(tmp_path, name, mark, codec):
    if codec != "utf-8" and name.endswith(".ply"):
        pytest.skip("PLY's header is ASCII before a binary body: no UTF-16")
    plain, marked = tmp_path / name, tmp_path / f"bom_{name}"
    plain.write_text(TEXT_MESHES[name])
    marked.write_bytes(mark + TEXT_MESHES[name].encode(codec))
    want, got = read_asset(plain), read_asset(marked)
    assert len(got.faces) == 2 and corners(got) == corners(want) == TWO_TRIANGLES
    assert (got.meters_per_unit, got.up_axis) == (want.meters_per_unit, want.up_axis)
    if name.endswith(".usda"):
        assert got.meters_per_unit == 0.5 and asset_gravity(str(marked)) == (0.0, 0.0, -1.0)


def test_gltf_json_with_a_byte_order_mark_reads(tmp_path):
    files = trimesh.Scene(trimesh.creation.box()).export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(codecs.BOM_UTF8 * name.endswith(".gltf") + data)
    asset = read_asset(tmp_path / "model.gltf")
    assert len(asset.faces) == 12 and np.allclose(np.ptp(asset.vertices, axis=0), 1.0)


# ---------------------------------------------------------------- compressed and extended glTF
def glb(tree: dict, binary: bytes) -> bytes:
    """A GLB file: the JSON chunk (padded with spaces) and the binary chunk (with zeros)."""
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def draco_glb(mesh: trimesh.Trimesh, node: dict) -> bytes:
    """``mesh`` Draco-compressed (14-bit positions, as Blender writes them) in a GLB whose one
    node is ``node`` (its translation, rotation, scale)."""
    import DracoPy

    blob = DracoPy.encode(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32),
                          quantization_bits=14, compression_level=7)
    position = DracoPy.decode(blob).attributes[0]["unique_id"]
    tree = {
        "asset": {"version": "2.0", "generator": "hand-built"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, **node}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4, "extensions": {
            "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": position}}}}]}],
        "accessors": [
            {"componentType": 5126, "type": "VEC3", "count": len(mesh.vertices),
             "min": mesh.bounds[0].tolist(), "max": mesh.bounds[1].tolist()},
            {"componentType": 5125, "type": "SCALAR", "count": mesh.faces.size}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}],
        "buffers": [{"byteLength": len(blob)}],
        "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"],
    }
    return glb(tree, blob)


def plain_gltf(extensions: list[str], normalized: bool = False) -> dict:
    """A one-triangle .gltf (its buffer inline) that requires ``extensions``."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    data = base64.b64encode(points.tobytes()).decode()
    return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
                           "min": [0, 0, 0], "max": [1, 1, 0], **({"normalized": True} if normalized else {})}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "buffers": [{"byteLength": 36, "uri": f"data:application/octet-stream;base64,{data}"}],
            "extensionsUsed": extensions, "extensionsRequired": extensions}


def test_a_draco_glb_reads_as_the_same_mesh_uncompressed(tmp_path):
    pytest.importorskip("DracoPy")
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    node = {"translation": [1.0, 2.0, 0.0], "scale": [2.0, 2.0, 2.0]}
    path = tmp_path / "ball.glb"
    path.write_bytes(draco_glb(mesh, node))
    asset = read_asset(path)
    assert asset.faces.shape == mesh.faces.shape and asset.meters_per_unit == 1.0 and asset.up_axis == "Y"
    want = mesh.vertices * 2.0 + [1.0, 2.0, 0.0]
    # Draco orders vertices its own way; 14 bits over the 0.3 m ball, scaled by 2, move each
    # one less than 0.6 m / 2**14 along each axis
    moved, _ = cKDTree(want).query(asset.vertices)
    assert moved.max() < np.sqrt(3) * 0.6 / 2**14
    placed = trimesh.Trimesh(asset.vertices, asset.faces)
    assert placed.is_watertight and placed.volume == pytest.approx(mesh.volume * 8, rel=1e-3)


def test_a_draco_glb_without_dracopy_says_what_to_install(tmp_path, monkeypatch):
    pytest.importorskip("DracoPy")
    path = tmp_path / "ball.glb"
    path.write_bytes(draco_glb(trimesh.creation.box(), {}))
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # the import raises ImportError
    with pytest.raises(InputError, match="Draco-compressed .*pip install DracoPy"):
        read_asset(path)


@pytest.mark.parametrize("extensions, normalized, refused", [
    (["EXT_meshopt_compression"], False, "EXT_meshopt_compression"),
    (["KHR_texture_transform", "EXT_mesh_gpu_instancing"], False, "EXT_mesh_gpu_instancing"),
    (["KHR_mesh_quantization"], True, "KHR_mesh_quantization"),
    (["KHR_mesh_quantization"], False, None),
    (["KHR_materials_pbrSpecularGlossiness", "KHR_texture_transform", "KHR_lights_punctual"], False, None),
])
def test_a_required_gltf_extension_is_read_or_refused_by_name(tmp_path, extensions, normalized, refused):
    path = tmp_path / "tri.gltf"
    path.write_text(json.dumps(plain_gltf(extensions, normalized)))
    as_glb = tmp_path / "tri.glb"
    tree = plain_gltf(extensions, normalized)
    binary = base64.b64decode(tree["buffers"][0].pop("uri").partition(",")[2])
    as_glb.write_bytes(glb(tree, binary))
    for file in (path, as_glb):
        if refused:
            with pytest.raises(InputError) as info:
                read_asset(file)
            message = str(info.value)
            assert "\n" not in message and f"requires the extension {refused}, which icefarm cannot read" in message
        else:
            assert read_asset(file).faces.tolist() == [[0, 1, 2]]


# ---------------------------------------------------------------- a reused job folder
def test_a_second_job_into_the_same_folder_clears_the_first(tmp_path, sphere):
    mesh = tmp_path / "sphere.ply"
    sphere.export(mesh)
    spec = JobSpec("sphere", str(mesh), 0.3, params.resolve({"storm.mode": "relative", "water.rays": 500}), seed=3)
    job_dir = tmp_path / "job"
    assert run_job(spec, job_dir, until=Stage.WATER).status == "done"
    # what a full earlier job and its later render and export had left, and a file of the user's
    earlier = ["render.png", "render.exr", "scene.usda", "ice.usdc", "ice.ply", "drips.json", "render_view1.png",
               "render_povray.png", "sky_az135_el30.exr", "growth/frame_0001.png", "renders/final/render.png",
               "export/scene.usdz"]
    for name in earlier + ["notes.txt"]:
        (job_dir / name).parent.mkdir(parents=True, exist_ok=True)
        (job_dir / name).write_bytes(b"earlier")
    assert run_job(spec, job_dir, until=Stage.WATER).status == "done"
    assert not [name for name in earlier if (job_dir / name).exists()]
    assert (job_dir / "notes.txt").read_bytes() == b"earlier"
    listed = json.loads((job_dir / "done.json").read_text())["artifacts"]
    assert "water.ply" in listed and not set(listed) & set(earlier)
    assert check_done(job_dir) is None


# ---------------------------------------------------------------- a full disk
def test_a_full_disk_in_run_is_one_line(tmp_path, sphere, monkeypatch):
    from click.testing import CliRunner

    from icefarm import artifacts
    from icefarm.cli import main

    def full(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    mesh = tmp_path / "sphere.ply"
    sphere.export(mesh)
    monkeypatch.setattr(artifacts, "atomic_write", full)
    spec = JobSpec("sphere", str(mesh), 0.3, params.resolve({"storm.mode": "relative", "water.rays": 500}), seed=3)
    with pytest.raises(InputError, match="No space left on device") as info:
        run_job(spec, tmp_path / "job", until=Stage.WATER)
    assert info.value.__suppress_context__ and "\n" not in str(info.value)

    result = CliRunner().invoke(main, ["run", str(mesh), "--size-m", "0.3", "-o", str(tmp_path / "cli"),
                                       "--until", "water", "--no-render", "--set", "water.rays=500"])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert lines[-1].startswith(f"error: cannot write the job folder {tmp_path / 'cli'}: No space left on device")


# ---------------------------------------------------------------- a read-only shared cache
def read_only(monkeypatch, folder):
    """Make writes under ``folder`` fail as a read-only folder's do (EACCES), for root too."""
    from icefarm import artifacts

    write = artifacts.atomic_write

    def refuse(path, data):
        if Path(path).resolve().is_relative_to(folder.resolve()):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        write(path, data)

    monkeypatch.setattr(artifacts, "atomic_write", refuse)


def test_a_read_only_cache_is_read_and_the_rest_computed(tmp_path, sphere, monkeypatch):
    mesh = tmp_path / "sphere.ply"
    sphere.export(mesh)
    p = params.resolve({"storm.mode": "relative", "water.rays": 500, "drips.count": 10})
    cache = tmp_path / "shared"
    spec = JobSpec("sphere", str(mesh), 0.3, p, seed=3)
    assert run_job(spec, tmp_path / "a", cache, until=Stage.WATER).status == "done"
    entries = sorted(cache.rglob("*.npz"))
    read_only(monkeypatch, cache)
    assert not write_policy(cache, ["drips"])
    outcome = run_job(JobSpec("sphere", str(mesh), 0.3, p, seed=3), tmp_path / "b", cache, until=Stage.DRIPS)
    assert outcome.status == "done" and outcome.reused == ("water",)
    assert sorted(cache.rglob("*.npz")) == entries  # drips computed, not stored


def test_a_chmod_read_only_cache_is_seen_as_such(tmp_path):
    cache = tmp_path / "shared"
    cache.mkdir()
    cache.chmod(0o555)
    try:
        if os.access(cache, os.W_OK):
            pytest.skip("this user (root) writes a folder chmod made read-only")
        assert StageCache(cache).read_only and not write_policy(cache, [])
    finally:
        cache.chmod(0o755)


BLENDER_PYTHON = Path(__file__).resolve().parents[1] / ".venv-blender" / "bin" / "python"
BLENDER_GLB = """
import sys
import bpy
src, plain, draco = sys.argv[1:4]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.obj_import(filepath=src, forward_axis="NEGATIVE_Z", up_axis="Y")
for path, on in ((plain, False), (draco, True)):
    bpy.ops.export_scene.gltf(filepath=path, export_format="GLB", export_draco_mesh_compression_enable=on,
                              export_draco_position_quantization=14, export_apply=True)
"""


@pytest.mark.slow  # Blender exports, then twelve jobs' first stages
@pytest.mark.skipif(not BLENDER_PYTHON.is_file(), reason="no .venv-blender with bpy (.ci/setup.sh makes it)")
def test_blenders_draco_glb_grows_the_ice_of_its_plain_glb(tmp_path):
    import subprocess

    from icefarm.generators import generate

    generate("table").export(tmp_path / "table.obj")
    plain, draco = tmp_path / "plain.glb", tmp_path / "draco.glb"
    subprocess.run([str(BLENDER_PYTHON), "-c", BLENDER_GLB, str(tmp_path / "table.obj"), str(plain), str(draco)],
                   check=True, capture_output=True, timeout=300)
    assert b"KHR_draco_mesh_compression" in draco.read_bytes() and draco.stat().st_size < plain.stat().st_size / 2
    figures = {}
    for path in (plain, draco):
        spec = JobSpec(object_id=path.stem, mesh=str(path), size_m=None, params=params.resolve({}), seed=0)
        runs = []
        for seed in range(1, 7):  # Draco reorders the vertices: each seed is another draw of the fringe
            job = tmp_path / f"{path.stem}{seed}"
            assert run_job(dataclasses.replace(spec, seed=seed), job, until=Stage.DRIPS).error is None
            runs.append(json.loads((job / "timings.json").read_text()))
        figures[path.stem] = (np.mean([r["icicles"] for r in runs]), runs[0]["storm_glaze_p50_mm"])
    (count, glaze), (count_draco, glaze_draco) = figures["plain"], figures["draco"]
    assert abs(count_draco - count) <= 0.05 * count and abs(glaze_draco - glaze) <= 0.05 * glaze
