"""Assets with their real size: USD stages and glTF scenes keep their units, transforms and up
axis (gravity follows it), OBJ/PLY/STL/OFF need a size, latin-1 text files load, and a single
flat sheet runs."""

import json

import numpy as np
import pytest
import trimesh
import yaml
from click.testing import CliRunner

from icefarm import params
from icefarm.asset_io import asset_gravity, fan_triangulate, read_asset, with_asset_gravity
from icefarm.cli import main
from icefarm.errors import InputError
from icefarm.farm.manifest import load_manifest
from icefarm.mesh import prepare


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def usd_mesh(name: str, points, counts, indices, extra: str = "", metadata: str = "") -> str:
    """One ``def Mesh`` block of a .usda file."""
    pts = ", ".join(f"({x:g}, {y:g}, {z:g})" for x, y, z in points)
    return (f'def Mesh "{name}" {metadata}\n{{\n    int[] faceVertexCounts = {list(counts)}\n'
            f'    int[] faceVertexIndices = {list(indices)}\n    point3f[] points = [{pts}]\n{extra}}}\n')


def cube(size: float):
    """A cube from 0 to ``size`` as quads (outward, counter-clockwise seen from outside)."""
    p = np.array([[x, y, z] for z in (0, size) for y in (0, size) for x in (0, size)], dtype=float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    return p, [4] * 6, [i for q in quads for i in q]


def hex_prism(radius: float, height: float):
    """A hexagonal prism along +Z: two hexagons (6-gons) and six quads."""
    a = np.radians(np.arange(6) * 60.0)
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros(6)])
    p = np.vstack([ring, ring + [0, 0, height]])
    faces = [[5, 4, 3, 2, 1, 0], [6, 7, 8, 9, 10, 11]] + [[i, (i + 1) % 6, (i + 1) % 6 + 6, i + 6] for i in range(6)]
    return p, [len(f) for f in faces], [i for f in faces for i in f]


def write_stage(path, meters_per_unit=0.01, up_axis="Z"):
    """A stage in centimetres, Z up: a hexagonal post (5 cm radius, 50 cm high) at the origin
    and a 10 cm cube scaled 2x and moved 100 cm along X; an invisible and a guide mesh far
    away that must not count."""
    post = usd_mesh("Post", *hex_prism(5, 50))
    box = usd_mesh("Box", *cube(10))
    hidden = usd_mesh("Hidden", *cube(1000), extra='    token visibility = "invisible"\n')
    guide = usd_mesh("Guide", *cube(5000), extra='    uniform token purpose = "guide"\n')
    text = (f'#usda 1.0\n(\n    metersPerUnit = {meters_per_unit}\n    upAxis = "{up_axis}"\n)\n'
            'def Xform "World"\n{\n' + post + hidden + guide +
            'def Xform "Panel"\n{\n    double3 xformOp:translate = (100, 0, 0)\n'
            '    double3 xformOp:scale = (2, 2, 2)\n'
            '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n' + box + '}\n}\n')
    path.write_text(text)
    return path


# The stage's extent in meters: x from -5 to 120 cm, y from -4.33 to 20 cm, z from 0 to 50 cm.
STAGE_EXTENTS_M = np.array([1.25, 0.20 + 0.05 * np.sin(np.radians(60)), 0.50])


@pytest.fixture
def stage(tmp_path):
    return write_stage(tmp_path / "post.usda")


def test_fan_triangulation_of_triangles_quads_and_ngons():
    faces = fan_triangulate([3, 4, 5, 2], [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13])
    assert faces.tolist() == [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11]]
    holes = fan_triangulate([3, 4], [0, 1, 2, 3, 4, 5, 6], keep=np.array([True, False]))
    assert holes.tolist() == [[0, 1, 2]]


def test_usd_stage_keeps_units_transforms_and_up_axis(stage):
    asset = read_asset(stage)
    assert asset.meters_per_unit == pytest.approx(0.01) and asset.up_axis == "Z"
    assert asset.gravity == (0.0, 0.0, -1.0) and asset_gravity(str(stage)) == (0.0, 0.0, -1.0)
    mesh = trimesh.Trimesh(asset.vertices, asset.faces)
    # two closed pieces, hexagons and quads fanned with their winding: outward, the right volume
    assert mesh.is_watertight and mesh.body_count == 2 and mesh.volume > 0
    hexagon = 3 * np.sqrt(3) / 2 * 5 ** 2
    assert mesh.volume == pytest.approx(hexagon * 50 + 20 ** 3)
    assert np.allclose(mesh.bounds[0][[0, 2]], [-5, 0]) and np.allclose(mesh.bounds[1], [120, 20, 50])

    prepared = prepare(stage, None, asset.gravity)  # no size: the stage's own, in meters
    assert np.allclose(prepared.mesh.extents, STAGE_EXTENTS_M, atol=1e-9)
    assert prepared.scale == pytest.approx(0.01)


def test_a_size_still_rescales_a_usd_stage(stage):
    prepared = prepare(stage, 1.0, (0.0, 0.0, -1.0))  # 1 m high along Z instead of 0.5 m
    assert np.allclose(prepared.mesh.extents, STAGE_EXTENTS_M * 2, atol=1e-9)


def test_usd_fallbacks_and_mirroring(tmp_path):
    """A Y-up stage in meters; a mirroring transform keeps the faces outward."""
    p, counts, indices = cube(1)
    text = ('#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n'
            'def Xform "M"\n{\n    double3 xformOp:scale = (-1, 1, 1)\n'
            '    uniform token[] xformOpOrder = ["xformOp:scale"]\n' + usd_mesh("C", p, counts, indices) + '}\n')
    path = tmp_path / "mirror.usda"
    path.write_text(text)
    asset = read_asset(path)
    assert asset.up_axis == "Y" and asset.gravity == (0.0, -1.0, 0.0)
    mesh = trimesh.Trimesh(asset.vertices, asset.faces)
    assert mesh.volume == pytest.approx(1.0) and mesh.bounds[0][0] == pytest.approx(-1.0)


def test_glb_node_transforms_are_applied(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    moved = trimesh.transformations.translation_matrix([2.0, 0.5, 0.0]) @ np.diag([0.5, 0.5, 0.5, 1.0])
    scene.add_geometry(box, node_name="near", geom_name="box", transform=moved)
    scene.add_geometry(box, node_name="far", geom_name="box",
                       transform=trimesh.transformations.translation_matrix([-1.0, 0.0, 0.0]))
    path = tmp_path / "two_boxes.glb"
    path.write_bytes(scene.export(file_type="glb"))

    asset = read_asset(path)
    assert asset.meters_per_unit == 1.0 and asset.gravity == (0.0, -1.0, 0.0)
    mesh = trimesh.Trimesh(asset.vertices, asset.faces)
    assert np.allclose(mesh.bounds, [[-1.5, -0.5, -0.5], [2.25, 0.75, 0.5]])
    assert mesh.volume == pytest.approx(1.0 + 0.125)
    assert np.allclose(prepare(path, None).mesh.extents, [3.75, 1.25, 1.0])
    assert np.allclose(prepare(path, 2.5).mesh.extents, [7.5, 2.5, 2.0])  # 1.25 m high, made 2.5 m


def test_cli_keeps_the_size_and_follows_the_up_axis(stage, tmp_path):
    out = tmp_path / "job"
    result = run("run", stage, "-o", out, "--until", "water", "--set", "water.rays=300")
    assert result.exit_code == 0, result.output
    p = yaml.safe_load((out / "params.yaml").read_text())
    assert p["water"]["gravity"] == [0.0, 0.0, -1.0]  # the params actually used
    water = trimesh.load(out / "water.ply", process=False)
    assert np.allclose(water.extents, STAGE_EXTENTS_M, atol=1e-6)

    mine = tmp_path / "mine"
    assert run("run", stage, "-o", mine, "--until", "water", "--set", "water.rays=300",
               "--set", "water.gravity=[0,-1,0]").exit_code == 0
    assert yaml.safe_load((mine / "params.yaml").read_text())["water"]["gravity"] == [0.0, -1.0, 0.0]


def test_with_asset_gravity_leaves_a_set_gravity(stage, tmp_path):
    assert with_asset_gravity(str(stage), {}) == {"water.gravity": [0.0, 0.0, -1.0]}
    assert with_asset_gravity(str(stage), {"water.gravity": [1, 0, 0]}) == {"water.gravity": [1, 0, 0]}
    assert with_asset_gravity(str(tmp_path / "x.obj"), {}) == {}
    assert with_asset_gravity("generator:table", {}) == {}


def test_obj_without_a_size_is_one_clear_line(tmp_path, sphere):
    path = tmp_path / "ball.obj"
    sphere.export(path)
    result = run("run", path, "-o", tmp_path / "out", "--no-render")
    assert result.exit_code == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "OBJ format carries no units" in lines[0] and "--size-m" in lines[0], lines
    assert not (tmp_path / "out" / "params.yaml").exists()
    with pytest.raises(InputError, match="carries no units"):
        prepare(path, None)


def test_manifest_size_m_is_optional_for_assets_with_units(stage, tmp_path, sphere):
    sphere.export(tmp_path / "ball.obj")
    data = {"name": "assets", "objects": [
        {"id": "post", "mesh": stage.name},
        {"id": "post2", "mesh": stage.name, "size_m": 1.0, "params": {"water": {"gravity": [0, -1, 0]}}},
        {"id": "table", "mesh": "generator:table"}]}
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(data))
    manifest = load_manifest(path)
    post, post2, table = manifest.objects
    assert post.size_m is None and post.params["water.gravity"] == [0.0, 0.0, -1.0]
    assert post2.size_m == 1.0 and post2.params["water.gravity"] == [0.0, -1.0, 0.0]  # set: kept
    assert table.size_m is None and "water.gravity" not in table.params
    assert params.resolve(manifest.defaults, post.params).water.gravity == (0.0, 0.0, -1.0)

    data["objects"].append({"id": "ball", "mesh": "ball.obj"})
    data["objects"].append({"id": "teapot", "mesh": "generator:teapot"})
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError) as caught:
        load_manifest(path)
    assert "objects[3].size_m:" in str(caught.value) and "OBJ format carries no units" in str(caught.value)
    assert "objects[4].size_m: generator:teapot is in arbitrary units" in str(caught.value)


LATIN1_OBJ = b"# caf\xe9 cr\xe8me, \x80 in cp1252\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
LATIN1_PLY = (b"ply\nformat ascii 1.0\ncomment mod\xe9lis\xe9\nelement vertex 3\nproperty float x\n"
              b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
              b"end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")


def test_latin1_text_files_load(tmp_path):
    (tmp_path / "sign.obj").write_bytes(LATIN1_OBJ)
    (tmp_path / "tri.ply").write_bytes(LATIN1_PLY)
    binary = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]).export(file_type="ply")
    (tmp_path / "binary.ply").write_bytes(binary.replace(b"ply\n", b"ply\ncomment caf\xe9\n", 1))
    (tmp_path / "tri.stl").write_bytes(b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n"
                                       b"vertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid caf\xe9\n")
    assert len(read_asset(tmp_path / "sign.obj").faces) == 2
    for name in ("tri.ply", "binary.ply", "tri.stl"):
        asset = read_asset(tmp_path / name)
        assert asset.faces.tolist() == [[0, 1, 2]] and asset.meters_per_unit is None, name
        assert np.allclose(asset.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]]), name
    assert prepare(tmp_path / "sign.obj", 0.5).problems.watertight  # a sign plate, solidified


def level_sheet(noise: float, n: int = 6) -> trimesh.Trimesh:
    """A 1 m level grid as a DCC writes it: level to ``noise`` meters."""
    x, z = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    v = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    v += np.random.default_rng(1).normal(0, noise, v.shape)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + 1, a + n + 2]), np.column_stack([a, a + n + 2, a + n + 1])])
    return trimesh.Trimesh(v, faces, process=False)


@pytest.mark.parametrize("noise", [0.0, 1e-7, 1e-6])
def test_a_level_sheet_keeps_its_size(noise):
    """Its float noise is no height: size_m is its width (the noise made it 10,000 km wide)."""
    prepared = prepare(level_sheet(noise), 1.0)
    assert prepared.mesh.extents.max() == pytest.approx(1.0, rel=1e-3)
    assert prepared.mesh.extents[1] < 0.01


@pytest.mark.parametrize("kind", ["level, float noise", "upright quad", "tilted quad"])
def test_a_single_sheet_runs_end_to_end(tmp_path, kind):
    if kind == "level, float noise":
        sheet = level_sheet(1e-7)
    else:
        quad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], [[0, 1, 2], [0, 2, 3]])
        angle = 30 if kind == "tilted quad" else 90
        sheet = quad.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle), [1, 0, 0]))
    path = tmp_path / "sheet.obj"
    sheet.export(path)
    out = tmp_path / "job"
    result = run("run", path, "--size-m", 1, "--no-render", "-o", out, "--until", "surface",
                 "--set", "water.rays=2000", "--set", "drips.count=6", "--placement", "hanging",
                 # a light storm, few icicles, a coarse proxy and flow mesh (the tilted quad's rims draw
                 # 192 icicles otherwise)
                 "--set", "storm.max_icicles=4", "--set", "storm.intensity=light", "--set", "proxy.face_budget=5000",
                 "--set", "storm.flow_edge=0.1",
                 "--set", "surface.voxel_size=0.008", "--set", "glaze.voxel_size=0.03")  # coarse: a quick run
    assert result.exit_code == 0, result.output
    timings = json.loads((out / "timings.json").read_text())
    assert timings["problems"]["boundary_edges"] == 0  # solidified: a closed slab
    assert (out / "ice.ply").is_file()


def test_a_mesh_wound_inside_out_is_turned_outward_and_catches_the_rain(tmp_path):
    """A DCC export wound inside out (normals pointing in), with holes like a scan's: prepare
    turns it outward and says so, and the storm glazes its top (wound inside out, a 0.3 m bunny
    caught no rain at all: no glaze, no icicles). A sheet has no inside and is left alone."""
    from icefarm.job import Stage, run_stages

    ball = trimesh.creation.icosphere(subdivisions=3)
    ball.update_faces(np.flatnonzero(ball.triangles_center[:, 1] > -0.9))  # a hole at the bottom
    ball.invert()
    ball.export(tmp_path / "inside_out.obj")
    prepared = prepare(tmp_path / "inside_out.obj", 0.3)
    mesh = prepared.mesh
    assert prepared.problems.inside_out_faces == len(mesh.faces) and prepared.problems.boundary_edges > 0
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - mesh.centroid)
    assert (outward > 0).all()
    p = params.resolve({})
    r = run_stages(prepare(tmp_path / "inside_out.obj", 0.3), p, 0, until=Stage.WATER)
    top = r.flow.vertices[:, 1] > 0.1
    assert np.median(r.water.storm.ice[top]) > 0.005  # centimetre glaze where the rain lands
    sheet = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0.2, 1], [0, 0.2, 1]], [[0, 2, 1], [0, 3, 2]])  # facing down
    sheet.export(tmp_path / "sheet.obj")
    assert prepare(tmp_path / "sheet.obj", 0.3).problems.inside_out_faces == 0
    assert prepare(tmp_path / "inside_out.obj", 0.3).problems == prepared.problems  # the same every time
    # A hollow ball's inner shell faces into its cavity on purpose: a piece inside another's
    # box is left as it is; when the whole ball comes inside out, only the outer shell turns.
    from icefarm.mesh import orient_outward

    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    inner.invert()
    hollow = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=2), inner])
    assert orient_outward(hollow)[1] == 0
    hollow.invert()
    turned, count = orient_outward(hollow)
    outer = np.linalg.norm(turned.triangles_center, axis=1) > 0.9
    assert count == outer.sum()
    np.testing.assert_array_equal(turned.faces[~outer], hollow.faces[~outer])
    assert (np.einsum("ij,ij->i", turned.face_normals, turned.triangles_center)[outer] > 0).all()
