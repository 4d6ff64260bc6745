"""Glaze ice (paper 4.4.4, Equation 3): a continuous clear coat, measured on the mesh."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from icefarm import params
from icefarm.generators import generate
from icefarm.mesh import prepare
from icefarm.metaballs import KAPPA, SPACING, Balls, fuse_fields, sample_field
from icefarm.spatial import inside, ray_caster
from icefarm.stages.surface.glaze import CoatSurface, glaze_balls, glaze_field, glaze_thickness, wet_vertices
from icefarm.stages.surface.glaze_measure import GlazeProbe, GlazeStats, measure_glaze
from icefarm.stages.water import RainOptions, WaterResult, compute_water

G = np.array([0.0, -1.0, 0.0])
BUNNY = Path(__file__).resolve().parents[1].parent / "shared" / "meshes" / "stanford-bunny.obj"
# Twice the default glaze voxel: the top/bottom ratio reads the same on a quarter of the faces.
COARSE = 0.008


def _glaze(**changes):
    """The resolved glaze group with ``name=value`` changes."""
    return params.resolve({f"glaze.{k}": v for k, v in changes.items()}).glaze


def _coat(mesh, water, glaze, exclude=None):
    field = glaze_field(mesh, water, glaze, np.random.default_rng(0), exclude=exclude)
    return fuse_fields(None, field)


def _closed(vertices, faces):
    m = trimesh.Trimesh(vertices, faces, process=False)
    assert len(faces) > 0
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0
    return m


def _grounded(mesh):
    """The pipeline's sole: vertices within 2 % of the height of the lowest point."""
    h = mesh.vertices @ -G
    return h < h.min() + 0.02 * np.ptp(h)


@pytest.fixture(scope="module")
def bunny_water():
    """The bunny at 0.3 m, wet by 400 rain rays, with its sole."""
    if not BUNNY.is_file():
        pytest.skip(f"{BUNNY} not available")
    mesh = prepare(BUNNY, 0.3, G).mesh
    return mesh, compute_water(mesh, G, RainOptions(400, 0.01), np.random.default_rng(0)), _grounded(mesh)


@pytest.fixture(scope="module")
def roof_water():
    """A small generated roof (0.5 m), wet by 400 rain rays, with its sole."""
    mesh = prepare(generate("roof", 2), 0.5, G).mesh
    return mesh, compute_water(mesh, G, RainOptions(400, 0.01), np.random.default_rng(0)), _grounded(mesh)


@pytest.mark.parametrize("case", [pytest.param("bunny_water", marks=pytest.mark.slow),  # ../shared/meshes
                                  "roof_water"])
def test_default_coat_covers_the_wet_surface_evenly(case, request):
    mesh, water, sole = request.getfixturevalue(case)
    v, f = _coat(mesh, water, _glaze(), exclude=sole)
    _closed(v, f)
    s = measure_glaze(v, f, CoatSurface(mesh, water, sole), G, GlazeProbe(samples=5000))
    assert isinstance(s, GlazeStats) and s.samples == 5000 and s.wet_area_m2 > 0
    assert s.coverage >= 0.95
    assert s.p90_mm <= 2 * s.p50_mm
    assert s.p50_mm >= 1.0  # thick enough to read as ice


def test_the_glaze_measure_reads_the_same_through_a_tree_of_the_faces_near_its_rays(roof_water, monkeypatch):
    from icefarm.stages.surface import glaze_measure

    mesh, water, sole = roof_water
    v, f = _coat(mesh, water, _glaze(), exclude=sole)
    whole = measure_glaze(v, f, CoatSurface(mesh, water, sole), G, GlazeProbe(samples=3000))
    monkeypatch.setattr(glaze_measure, "NEAR_CASTER_FACES", 0)  # big ice's near_caster on this small coat
    assert measure_glaze(v, f, CoatSurface(mesh, water, sole), G, GlazeProbe(samples=3000)) == whole


@pytest.mark.parametrize("case", [pytest.param("bunny_water", marks=pytest.mark.slow),  # ../shared/meshes
                                  "roof_water"])
def test_lifetime_puts_the_ice_high_up_or_low_down(case, request):
    mesh, water, sole = request.getfixturevalue(case)
    ratio = {}
    for lt in (0.0, 1.0):
        v, f = _coat(mesh, water, _glaze(lifetime=lt, voxel_size=COARSE), exclude=sole)
        ratio[lt] = measure_glaze(v, f, CoatSurface(mesh, water, sole), G, GlazeProbe(samples=2000)).top_bottom
    assert ratio[0.0] >= 3  # freezes where it lands: thick up high
    assert ratio[1.0] <= 1 / 3  # runs down first: thick low down


def test_lifetime_on_a_sphere_with_water_by_height(surface_kit):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.15)
    water = surface_kit.water(sphere, np.ones(len(sphere.vertices), dtype=bool))
    low, high = (measure_glaze(*_coat(sphere, water, _glaze(lifetime=lt, voxel_size=COARSE)),
                               CoatSurface(sphere, water), G, GlazeProbe(samples=4000)).top_bottom for lt in (0.0, 1.0))
    assert low >= 3 and high <= 1 / 3


def test_thickness_is_equation_3_on_a_flat_wet_plate():
    plate = trimesh.creation.box(extents=(0.2, 0.03, 0.2))
    plate = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plate.vertices, plate.faces, 0.02))
    top = plate.vertices[:, 1] > 0.0149
    x = plate.vertices[:, 0] + 0.1  # 0 .. 0.2 m across the plate
    n = len(x)
    water = WaterResult(top, np.where(top, 0.1, 0.0), np.zeros(n, int), np.where(top, x, 0.0),
                        np.zeros(n, int), np.where(top, 0.2 - x, 0.0), np.zeros((0, 3)))
    for lt in (0.0, 0.5, 1.0):
        glaze = _glaze(lifetime=lt, min_radius=0.001, scale=0.02)
        v, f = _coat(plate, water, glaze)
        ice = _closed(v, f)
        # Points on the top, away from its rim: the ice above them, straight up.
        px = np.linspace(-0.07, 0.07, 15)
        pts = np.stack(np.meshgrid(px, [0.015], px, indexing="ij"), axis=-1).reshape(-1, 3)
        up = np.broadcast_to(-G, pts.shape)
        d, face = ray_caster(ice)(pts - 1e-4 * up, up)
        assert np.isfinite(d).all() and (ice.face_normals[face] @ -G > 0).all()  # leaving the ice
        expected = 0.001 + 0.02 * ((pts[:, 0] + 0.1) * lt + (0.1 - pts[:, 0]) * (1 - lt))
        assert np.abs(d - 1e-4 - expected).max() <= glaze.voxel_size
        assert np.abs(d - 1e-4 - expected).mean() <= 0.25 * glaze.voxel_size
    assert np.allclose(glaze_thickness(water, glaze)[top], 0.001 + 0.02 * (x[top] * 1.0))


def test_coat_fuses_with_an_icicle_into_one_watertight_mesh(surface_kit):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    water = surface_kit.water(sphere, sphere.vertices[:, 1] < 0.08)  # all but a dry cap: one surface
    coat = glaze_field(sphere, water, _glaze(), np.random.default_rng(0))
    # An icicle: a chain of balls of radius 4 mm from inside the bottom down 6 cm.
    r = 0.004
    z = np.arange(-0.095, -0.16, -SPACING * KAPPA * r)
    chain = Balls(np.c_[np.zeros_like(z), z, np.zeros_like(z)], np.full(len(z), KAPPA * r), np.ones(len(z)))
    v, f = fuse_fields(sample_field(chain, 0.001), coat)
    ice = _closed(v, f)
    assert len(ice.split(only_watertight=False)) == 1
    assert ice.bounds[0, 1] < -0.155 and ice.bounds[1, 1] > 0.08  # icicle tip and coat top


def test_excluded_vertices_get_no_ice(surface_kit):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    wet = np.ones(len(sphere.vertices), dtype=bool)
    sole = sphere.vertices[:, 1] < -0.07
    water = surface_kit.water(sphere, wet)
    v, f = _coat(sphere, water, _glaze(), exclude=sole)
    ice = _closed(v, f)
    cast = ray_caster(ice)
    points = sphere.vertices[sole]
    normal = sphere.vertex_normals[sole]
    assert not inside(cast, points).any()
    d, _ = cast(points - 1e-4 * normal, normal)
    assert (d > 0.01).all()  # no ice over them, not even a thin one
    s = measure_glaze(v, f, CoatSurface(sphere, water, sole), G, GlazeProbe(samples=4000))
    assert s.coverage >= 0.95


def test_legacy_zero_balls_means_no_glaze(surface_kit):
    glaze = params.resolve({"glaze.balls": 0}).glaze
    assert glaze.mode == "none" and not hasattr(glaze, "balls")
    assert params.resolve({"glaze": {"balls": 0}}, {"drips.count": 3}).glaze.mode == "none"
    assert params.parse_assignment("glaze.balls=0") == ("glaze.balls", 0)
    assert params.resolve({"glaze.balls": 0, "glaze.mode": "coat"}).glaze.mode == "coat"
    with pytest.warns(FutureWarning, match="legacy"):
        assert params.resolve({"glaze.balls": 5000}).glaze.mode == "coat"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert params.resolve().glaze.mode == "coat"
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    water = surface_kit.water(sphere, np.ones(len(sphere.vertices), dtype=bool))
    assert glaze_field(sphere, water, glaze, np.random.default_rng(0)) is None


def test_metaballs_mode_spreads_balls_by_density(surface_kit):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    water = surface_kit.water(sphere, sphere.vertices[:, 1] > 0)
    wet = wet_vertices(water)
    area = sphere.area_faces[wet[sphere.faces].sum(axis=1) >= 2].sum()
    balls = glaze_balls(sphere, water, _glaze(mode="metaballs", density=20000.0), np.random.default_rng(0))
    assert len(balls) == round(20000 * area)
    assert (balls.centers[:, 1] > -0.02).all()
    field = glaze_field(sphere, water, _glaze(mode="metaballs"), np.random.default_rng(0))
    _closed(*fuse_fields(None, field))


def test_dry_surface_or_no_ice_measures_as_such(surface_kit):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    n = len(sphere.vertices)
    dry = surface_kit.dry(sphere)
    assert glaze_field(sphere, dry, _glaze(), np.random.default_rng(0)) is None
    s = measure_glaze(np.zeros((0, 3)), np.zeros((0, 3), int), CoatSurface(sphere, dry), G)
    assert s.wet_area_m2 == 0 and math.isnan(s.coverage)
    wet = surface_kit.water(sphere, np.ones(n, dtype=bool))
    s = measure_glaze(np.zeros((0, 3)), np.zeros((0, 3), int), CoatSurface(sphere, wet), G, GlazeProbe(samples=100))
    assert s.coverage == 0 and math.isnan(s.p50_mm)


def test_a_coat_follows_a_steep_thickness_slope_without_steps():
    """The thickness changes by 1 mm per cm across a plate: the coat's outer face follows it
    as one sloped plane. Each lattice sample took the thickness of its nearest surface
    sample (one plateau per sample: 0.46 mm off here), which the sun picked out
    as a hammered-glass glitter on a car's windscreen."""
    plate = trimesh.creation.box(extents=(0.2, 0.03, 0.2))
    plate = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plate.vertices, plate.faces, 0.02))
    top = plate.vertices[:, 1] > 0.0149
    x = plate.vertices[:, 0] + 0.1
    n = len(x)
    water = WaterResult(top, np.where(top, 0.1, 0.0), np.zeros(n, int), np.where(top, x, 0.0),
                        np.zeros(n, int), np.where(top, 0.2 - x, 0.0), np.zeros((0, 3)))
    glaze = _glaze(lifetime=1.0, min_radius=0.002, scale=0.1)
    ice = _closed(*_coat(plate, water, glaze))
    px = np.linspace(-0.07, 0.07, 57)
    pts = np.stack(np.meshgrid(px, [0.015], px, indexing="ij"), axis=-1).reshape(-1, 3)
    up = np.broadcast_to(-G, pts.shape)
    d, _ = ray_caster(ice)(pts - 1e-4 * up, up)
    error = d - 1e-4 - (0.002 + 0.1 * (pts[:, 0] + 0.1))
    assert np.abs(error).max() <= 0.05 * glaze.voxel_size


def test_a_coat_over_noisy_thickness_stays_within_the_thickness_it_was_given():
    """Vertex thicknesses alternating between 5 and 15 mm: the thickness carried along each
    face's steep slope stays within what the face and its neighbours hold (unbounded, the
    slopes of small faces carried it into lumps of +-5 mm past them on a car's windscreen)."""
    plate = trimesh.creation.box(extents=(0.2, 0.03, 0.2))
    plate = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plate.vertices, plate.faces, 0.01))
    top = plate.vertices[:, 1] > 0.0149
    n = len(top)
    noisy = np.where(np.arange(n) % 3 == 0, 0.015, 0.005)
    water = WaterResult(top, np.where(top, 0.1, 0.0), np.zeros(n, int), np.where(top, noisy / 0.02, 0.0),
                        np.zeros(n, int), np.zeros(n), np.zeros((0, 3)))
    ice = _closed(*_coat(plate, water, _glaze(lifetime=1.0, min_radius=0.0, scale=0.02)))
    px = np.linspace(-0.07, 0.07, 57)
    pts = np.stack(np.meshgrid(px, [0.015], px, indexing="ij"), axis=-1).reshape(-1, 3)
    up = np.broadcast_to(-G, pts.shape)
    d, _ = ray_caster(ice)(pts - 1e-4 * up, up)
    height = d - 1e-4
    assert height.min() >= 0.005 - 0.001 and height.max() <= 0.015 + 0.001


def test_water_on_a_wrap_is_carried_to_the_object_under_it():
    """Over a wrap the coat grows on the object itself (`carry_water`): the object's own
    surface, its long edges split, each vertex wet as the wrap is nearest to it, and none of
    the object farther inside than the reach (surface the wrap left out) wet at all; the coat
    grown on it starts at the object, not at the wrap 4 mm above."""
    from icefarm.stages.surface.glaze import carry_water

    outer = trimesh.creation.icosphere(subdivisions=2, radius=0.1)  # long edges (~2 cm)
    hidden = trimesh.creation.icosphere(subdivisions=1, radius=0.02)  # a piece deep inside
    obj = trimesh.util.concatenate([outer, hidden])
    wrap = trimesh.creation.icosphere(subdivisions=4, radius=0.104)
    n = len(wrap.vertices)
    top = wrap.vertices[:, 1] > 0
    water = WaterResult(top, np.where(top, 0.1, 0.0), np.zeros(n, int), np.where(top, 0.05, 0.0),
                        np.zeros(n, int), np.where(top, 0.05, 0.0), np.zeros((0, 3)))
    side = wrap.vertices[:, 0] > 0.05
    carried = carry_water(obj, wrap, water, side, reach=0.008)
    v = carried.mesh.vertices
    assert len(carried.mesh.faces) > len(obj.faces)  # split to follow the water
    assert carried.mesh.edges_unique_length.max() <= 3.0 * np.median(wrap.edges_unique_length) * 1.001
    r = np.linalg.norm(v, axis=1)
    on_outer = r > 0.05
    assert np.all(r[on_outer] <= 0.1 + 1e-9)  # the object's surface (on or inside the sphere)
    wet = wet_vertices(carried.water)
    assert wet[on_outer & (v[:, 1] > 0.01)].all() and not wet[on_outer & (v[:, 1] < -0.01)].any()
    assert not wet[~on_outer].any()  # 8 cm under the wrap
    assert carried.exclude[on_outer & (v[:, 0] > 0.06)].all() and not carried.exclude[v[:, 0] < 0.04].any()
    glaze = _glaze(min_radius=0.002, scale=0.0, voxel_size=0.002)
    ice = _closed(*_coat(carried.mesh, carried.water, glaze))
    below = np.array([[0.0, 0.097, 0.0], [0.03, 0.094, 0.0]])  # 3 mm under the object's top: in the coat's inner part
    assert inside(ray_caster(ice), below).all()


def test_an_inside_out_piece_under_a_wrap_is_turned_whole():
    """A piece wound inward (prepare cannot turn the pieces of a mesh with non-manifold
    edges: a chair's seat) would grow its coat inside itself: `carry_water` turns each
    piece to face the way the wrap around it does, and leaves the others as they are."""
    from icefarm.stages.surface.glaze import carry_water

    right = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    wrong = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    wrong.apply_translation((0.2, 0.0, 0.0))
    wrong.invert()
    obj = trimesh.util.concatenate([right, wrong])
    wraps = [trimesh.creation.icosphere(subdivisions=3, radius=0.053) for _ in range(2)]
    wraps[1].apply_translation((0.2, 0.0, 0.0))
    wrap = trimesh.util.concatenate(wraps)
    n = len(wrap.vertices)
    water = WaterResult(np.ones(n, bool), np.full(n, 0.1), np.zeros(n, int), np.full(n, 0.05),
                        np.zeros(n, int), np.full(n, 0.05), np.zeros((0, 3)))
    carried = carry_water(obj, wrap, water, None, reach=0.006)
    centre = np.where(carried.mesh.triangles_center[:, :1] > 0.1, [0.2, 0.0, 0.0], [0.0, 0.0, 0.0])
    outward = np.einsum("kd,kd->k", carried.mesh.face_normals, carried.mesh.triangles_center - centre)
    assert (outward > 0).all()


def test_water_carried_from_a_wrap_skips_faces_buried_in_the_object():
    """Two boxes through each other (a kitbashed asset): the wrap's water reaches the faces
    of each that lie inside the other too, and a coat there would come out through the
    other's walls. Those faces get none: no wet face of the carried surface lies wholly inside
    the other box, while those wholly in the open stay wet."""
    from icefarm.spatial import inside, ray_caster
    from icefarm.stages.surface.glaze import carry_water

    a = trimesh.creation.box(extents=(0.2, 0.06, 0.06))
    b = trimesh.creation.box(extents=(0.06, 0.2, 0.06))
    obj = trimesh.util.concatenate([a, b])
    wrap = trimesh.creation.box(extents=(0.206, 0.206, 0.066))
    v, f = trimesh.remesh.subdivide_to_size(wrap.vertices, wrap.faces, max_edge=0.01)
    wrap = trimesh.Trimesh(v, f)
    n = len(wrap.vertices)
    water = WaterResult(np.ones(n, bool), np.full(n, 0.1), np.zeros(n, int), np.full(n, 0.05),
                        np.zeros(n, int), np.full(n, 0.05), np.zeros((0, 3)))
    carried = carry_water(obj, wrap, water, None, reach=0.2)
    m = carried.mesh
    wet = wet_vertices(carried.water, carried.exclude)
    glazed = (wet[m.faces].sum(axis=1) >= 2) & ~carried.exclude[m.faces].any(axis=1)
    corner = (m.vertices[m.faces] + 1e-4 * m.face_normals[:, None, :]).reshape(-1, 3)
    inner = (inside(ray_caster(a), corner) | inside(ray_caster(b), corner)).reshape(-1, 3)
    buried, open_ = inner.all(axis=1), ~inner.any(axis=1)  # (those across the seam are neither)
    assert buried.any() and not (glazed & buried).any()
    assert glazed[open_].mean() > 0.9


def test_runnels_streak_down_steep_faces_and_leave_level_ones_even():
    from icefarm.stages.surface.runnels import FLOOR, PEAK, runnel_relief

    g = np.array([0.0, -1.0, 0.0])
    x, y = np.meshgrid(np.linspace(0, 0.3, 121), np.linspace(0, 0.3, 121))
    wall = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])  # a wall facing +z
    rng = np.random.default_rng(0)
    f = runnel_relief(wall, np.tile([0.0, 0.0, 1.0], (len(wall), 1)), g, 0.5, rng)
    assert FLOOR <= f.min() and f.max() <= PEAK
    assert abs(f.mean() - 1.0) < 0.1 and f.std() > 0.15  # the ice moves into ridges, none is made
    grid = f.reshape(121, 121)  # rows down the wall (y), columns across it (x): 2.5 mm apart
    down = np.corrcoef(grid[:-4].ravel(), grid[4:].ravel())[0, 1]  # 1 cm down
    across = np.corrcoef(grid[:, :-4].ravel(), grid[:, 4:].ravel())[0, 1]  # 1 cm across
    assert down > across + 0.2  # streaks run down the slope
    top = np.column_stack([x.ravel(), np.zeros(x.size), y.ravel()])
    assert np.allclose(runnel_relief(top, np.tile([0.0, 1.0, 0.0], (len(top), 1)), g, 0.5, rng), 1.0)
    assert np.allclose(runnel_relief(wall, np.tile([0.0, 0.0, 1.0], (len(wall), 1)), g, 0.0, rng), 1.0)


def test_runnels_carve_the_coat_not_the_object(tmp_path):
    """A job's glaze on a box: its walls' coat strays from the storm's even thickness by the
    runnels (measured), its top stays even, and no coat vertex comes under CLEAR voxels."""
    import trimesh as tm

    from icefarm import params
    from icefarm.job import Stage, run_stages
    from icefarm.mesh import prepare
    from icefarm.stages.surface import measure_glaze

    box = tm.creation.box([0.3, 0.3, 0.3])
    figures = {}
    for runnels in (0.0, 0.5):
        p = params.resolve({"glaze.runnels": runnels, "drips.min_length": 1.0})  # glaze only
        prep = prepare(box, 0.3)
        r = run_stages(prep, p, 1, until=Stage.SURFACE)
        g = np.asarray(p.gravity)
        wet = r.wet  # the surface the glaze grew on
        figures[runnels] = measure_glaze(r.ice.vertices, r.ice.faces, wet, g)
    assert figures[0.0].relief < 0.08 and figures[0.5].relief > 0.15
    assert figures[0.5].coverage > 0.95


def test_the_glaze_stays_the_same_whatever_the_icicles_draw(surface_kit):
    """The glaze's random drops and runnels come from their own stream: one more icicle (more
    draws for its balls) leaves the coat away from the icicles as it was, so the cells of a
    sweep over the icicles share one glaze."""
    sphere = surface_kit.sphere(0.1)
    water = surface_kit.water(sphere, np.ones(len(sphere.vertices), dtype=bool))
    surface, glaze = surface_kit.groups(glaze__runnels=0.5)
    tops = []
    for starts in ([[0.0, -0.1, 0.0]], [[0.0, -0.1, 0.0], [0.03, -0.095, 0.0]]):
        drips = surface_kit.drips(sphere, starts)
        traj = surface_kit.straight(drips.positions, [0.05] * len(starts))
        r = surface_kit.ice(sphere, water, drips, traj, surface, glaze, seed=4)
        tops.append(r.vertices[r.vertices[:, 1] > 0.0])
    # the same coat to round-off (drawn with the icicles' stream, its runnels moved 0.8 mm)
    gap, _ = cKDTree(tops[0]).query(tops[1])
    assert len(tops[0]) > 100 and len(tops[1]) == len(tops[0]) and gap.max() < 1e-5
