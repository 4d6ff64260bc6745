"""What a user hands icefarm reads as they meant it: numbers in any notation, text with a
byte-order mark, compressed glTF, reused and full and read-only folders."""

from __future__ import annotations

import codecs

import numpy as np
import pytest
import trimesh

from icefarm.asset_io import asset_gravity, read_asset
from icefarm.farm.manifest import load_manifest
from icefarm.farm.points import parse_set
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
