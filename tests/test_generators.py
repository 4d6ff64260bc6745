"""The meshes icefarm builds itself: shape, cleanliness and the properties their docs promise."""

import numpy as np
import pytest
import trimesh

from icefarm import generators
from icefarm.errors import InputError
from icefarm.generators import branch, fountain, roof, teapot
from icefarm.mesh import clean, count_self_intersections, detect_problems

NAMES = ("teapot", "fountain", "roof", "branch")
CLOSED = ("fountain", "roof", "branch")
ASSETS = ("table", "bench", "car", "fence", "lamp", "shelter", "sign")


@pytest.fixture(scope="module")
def meshes():
    return {name: generators.generate(name) for name in NAMES}


def boundary_loops(mesh: trimesh.Trimesh) -> int:
    edges, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return len(trimesh.graph.connected_components(edges[counts == 1], min_len=1))


def test_names():
    assert generators.generator_names() == NAMES + ASSETS


@pytest.mark.parametrize("name", NAMES)
def test_sensible_mesh(meshes, name):
    mesh = meshes[name]
    assert isinstance(mesh, trimesh.Trimesh)
    assert 1000 <= len(mesh.faces) <= 10000  # "a few thousand" at the default detail
    assert np.isfinite(mesh.vertices).all()
    assert mesh.vertices[:, 1].min() == 0.0  # base on the ground, Y-up
    assert mesh.extents[1] > 0
    # Already clean: nothing to weld, no degenerate or duplicate faces.
    assert len(clean(mesh).faces) == len(mesh.faces)
    assert mesh.is_winding_consistent
    assert detect_problems(mesh).nonmanifold_edges == 0


@pytest.mark.parametrize("name", CLOSED)
def test_closed_meshes_are_one_outward_watertight_body(meshes, name):
    mesh = meshes[name]
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0
    problems = detect_problems(mesh)
    assert problems.components == 1 and problems.watertight
    assert mesh.euler_number == 2  # a sphere-like surface: no handles, no pinches


@pytest.mark.parametrize("name", ["fountain", "branch"])
def test_no_self_intersections(meshes, name):
    # (The roof is left out: pymeshlab reports false positives on its flat, tilted fans.)
    assert count_self_intersections(meshes[name]) == 0


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_and_detail_scales(name):
    a, b = generators.generate(name, 3), generators.generate(name, 3)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert len(generators.generate(name, 12).faces) > 2 * len(a.faces)


def test_teapot_is_the_classic_open_teapot(meshes):
    assert teapot._TEAPOT_POINTS.shape == (306, 3)
    assert teapot._TEAPOT_PATCHES.shape == (32, 4, 4)
    mesh = meshes["teapot"]
    detail = generators.DEFAULT_DETAIL
    assert len(mesh.faces) == 64 * detail ** 2 - 8 * detail
    assert len(generators.generate("teapot", 2).faces) == 64 * 4 - 16
    # Y-up, as tall as the lid knob, spout towards +x, handle towards -x.
    np.testing.assert_allclose(mesh.bounds, [[-3.0, 0.0, -2.0], [3.434, 3.15, 2.0]], atol=1e-3)
    problems = detect_problems(mesh)
    assert problems.components == 4  # body, lid, handle, spout
    assert not mesh.is_watertight and boundary_loops(mesh) == 6
    assert mesh.volume > 0  # normals face out of the pot


def test_fountain_upper_basin_overhangs_the_lower_one(meshes):
    mesh = meshes["fountain"]
    assert len(mesh.faces) == 2240  # the paper's Figure 16 b polygon count
    radius = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 2])
    lower_rim = mesh.vertices[radius > 0.9 * radius.max(), 1].max()
    centre = mesh.triangles_center
    centre_radius = np.hypot(centre[:, 0], centre[:, 2])
    down = mesh.face_normals[:, 1] < -0.5
    above = (centre[:, 1] > lower_rim) & (centre_radius < 0.9 * radius.max())
    assert (down & above).any()
    # The outermost ring of the upper basin is a lip with downward faces under it.
    upper = radius[mesh.vertices[:, 1] > lower_rim].max()
    assert (down & above & (centre_radius > 0.9 * upper)).any()


def test_roof_has_eaves(meshes):
    mesh = meshes["roof"]
    centre = mesh.triangles_center
    low_side = (np.abs(mesh.face_normals[:, 0]) > 0.99) & (centre[:, 1] < 0.25 * mesh.extents[1])
    walls = np.abs(centre[low_side, 0]).max()  # half the house's width
    # Soffits: downward faces outside the walls, above the ground.
    soffit = (mesh.face_normals[:, 1] < -0.5) & (np.abs(centre[:, 0]) > walls + 1e-6) & (centre[:, 1] > 0.1)
    assert soffit.any()
    assert mesh.extents[0] > 2 * walls


def test_branch_is_long_and_thin(meshes):
    mesh = meshes["branch"]
    assert mesh.extents[0] > 2 * max(mesh.extents[1], mesh.extents[2])
    assert mesh.volume < 0.05 * np.prod(mesh.extents)  # tubes, not a blob


def test_unknown_name_lists_names_and_hints():
    with pytest.raises(InputError) as err:
        generators.generate("fontain")
    message = str(err.value)
    assert "did you mean 'fountain'" in message
    assert all(name in message for name in NAMES)


@pytest.mark.parametrize("detail", [0, 65, 2.5, True, "8"])
def test_bad_detail(detail):
    with pytest.raises(InputError, match="detail"):
        generators.generate("fountain", detail)


def test_resample_polyline_keeps_corners_and_count():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])
    out = fountain.resample_polyline(points, 8)
    assert len(out) == 9
    assert all((np.abs(out - p).sum(axis=1) < 1e-12).any() for p in points)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=0), axis=1), 0.5)
    with pytest.raises(ValueError):
        fountain.resample_polyline(points, 1)


def test_lathe_makes_a_closed_cone():
    vertices, faces = fountain.lathe([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]], 256)
    cone = trimesh.Trimesh(vertices, faces, process=False)
    assert cone.is_watertight and cone.is_winding_consistent
    np.testing.assert_allclose(cone.volume, np.pi * 2 / 3, rtol=1e-3)
    with pytest.raises(ValueError):
        fountain.lathe([[0.5, 0.0], [1.0, 0.0], [0.0, 2.0]], 8)


def test_tube_and_prism_are_closed():
    t = np.linspace(0, 1, 9)
    line = np.c_[t, 0.1 * t ** 2, np.zeros_like(t)]
    tube = branch.tube(line, 0.1 - 0.05 * t, 12)
    assert tube.is_watertight and tube.is_winding_consistent and tube.volume > 0
    box = roof.prism([(0, 0), (2, 0), (2, 1), (0, 1)], [[0, 1, 2], [0, 2, 3]], 0.0, 3.0)
    assert box.is_watertight and box.is_winding_consistent
    np.testing.assert_allclose(box.volume, 6.0)
    with pytest.raises(ValueError):
        roof.prism([(0, 0), (0, 1), (2, 1), (2, 0)], [[0, 1, 2], [0, 2, 3]], 0.0, 3.0)


@pytest.fixture(scope="module")
def assets():
    return {name: generators.generate(name) for name in ASSETS}


@pytest.mark.parametrize("name", ASSETS)
def test_asset_is_one_closed_volume_at_its_real_size(assets, name):
    mesh = assets[name]
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.is_volume
    assert mesh.volume > 0  # outward-facing
    assert mesh.body_count == 1
    assert mesh.vertices[:, 1].min() == 0.0
    # Real size: the height is the natural size (manifold3d rounds to float32).
    np.testing.assert_allclose(mesh.extents[1], generators.natural_size(name), atol=1e-6)
    assert 12 <= len(mesh.faces) <= 1000  # box-modelled, low-poly
    assert len(clean(mesh).faces) == len(mesh.faces)
    assert detect_problems(mesh).nonmanifold_edges == 0
    # Deterministic, and detail leaves it alone.
    np.testing.assert_array_equal(generators.generate(name, 2).vertices, mesh.vertices)


def test_asset_sizes_are_real():
    expected = {"table": 0.74, "bench": 0.95, "car": 1.5, "fence": 1.0, "lamp": 3.5, "shelter": 2.5}
    assert {name: generators.natural_size(name) for name in expected} == expected
    assert all(generators.natural_size(name) is None for name in NAMES)
    with pytest.raises(InputError, match="did you mean 'bench'"):
        generators.natural_size("bnch")


def test_asset_footprints(assets):
    # Spot checks of the brief's sizes (meters): x by z.
    np.testing.assert_allclose(assets["table"].extents[[0, 2]], [0.9, 0.9])
    np.testing.assert_allclose(assets["car"].extents[0], 3.8)
    np.testing.assert_allclose(assets["fence"].extents[0], 2.4)
    shelter = assets["shelter"]
    # The roof overhangs: downward faces at the roof's underside outside the posts' footprint.
    centre, down = shelter.triangles_center, shelter.face_normals[:, 1] < -0.99
    assert (down & (centre[:, 1] > 2.2) & (np.abs(centre[:, 0]) > 1.45)).any()


def test_car_cabin_slopes_and_wheels_touch_the_ground(assets):
    car = assets["car"]
    normals, centre = car.face_normals, car.triangles_center
    sloped = (np.abs(normals[:, 1]) > 0.2) & (np.abs(normals[:, 1]) < 0.9) & (centre[:, 1] > 0.9)
    assert (sloped & (normals[:, 0] > 0)).any() and (sloped & (normals[:, 0] < 0)).any()  # windscreen, rear window
    on_ground = car.vertices[car.vertices[:, 1] == 0.0]
    assert len(np.unique(np.sign(on_ground[:, [0, 2]]), axis=0)) == 4  # one wheel at each corner
