"""Stage 2: where the drip points go (drips.distribution, drips.spacing) and coarse meshes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.distance import pdist

from icefarm import params
from icefarm.generators import generate
from icefarm.generators.fountain import lathe, resample_polyline
from icefarm.geometry import sample_faces
from icefarm.job.pipeline import JobSpec, Stage, run_job
from icefarm.mesh import detect_problems, prepare
from icefarm.stages.drips import DripOptions, drip_region, find_drips
from icefarm.stages.proxy import ProxyMethod, build_proxy
from icefarm.stages.proxy_checks import proxy_reason
from icefarm.stages.rims import drip_flux
from icefarm.stages.trajectories import grow_trajectories, trajectory_options
from icefarm.stages.water import RainOptions, compute_water

G = np.array([0.0, -1.0, 0.0])
DEFAULTS = params.resolve()

# An umbrella on a column, 0.45 tall: rain on its cone runs down to the rim at r = 0.30,
# y = 0.30; the underside rises from there to the column at y = 0.40.
UMBRELLA = np.array([[0.0, 0.0], [0.05, 0.0], [0.05, 0.40], [0.30, 0.30], [0.30, 0.32], [0.0, 0.45]])
UMBRELLA_RIM = (0.30, 0.30)


def umbrella(offset=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    vertices, faces = lathe(resample_polyline(UMBRELLA, 40), 48)
    return trimesh.Trimesh(vertices + np.asarray(offset), faces)


def off_the_ground(mesh: trimesh.Trimesh, fraction: float = 0.05) -> np.ndarray:
    """Vertices near the object's lowest point, as the pipeline's drips.ground_clearance."""
    heights = mesh.vertices[:, 1]
    return heights < heights.min() + fraction * np.ptp(heights)


def umbrella_drips(mesh, water, distribution, count=40, spacing=0.025, seed=3):
    options = DripOptions(count, 75.0, spacing=spacing, distribution=distribution,
                          exclude_vertices=off_the_ground(mesh))
    return find_drips(mesh, water, G, options, np.random.default_rng(seed))


@pytest.fixture(scope="module")
def wet_umbrella():
    mesh = umbrella()
    return mesh, compute_water(mesh, G, RainOptions(4000, 0.01), np.random.default_rng(1)).water


def rim_distance(points: np.ndarray, rim=UMBRELLA_RIM) -> np.ndarray:
    radius = np.hypot(points[:, 0], points[:, 2])
    return np.hypot(radius - rim[0], points[:, 1] - rim[1])


@pytest.mark.parametrize("distribution", ["water", "area"])
def test_drip_points_keep_the_spacing(sphere, distribution):
    water = compute_water(sphere, G, RainOptions(4000, 0.01), np.random.default_rng(2)).water
    drips = find_drips(sphere, water, G, DripOptions(40, 75.0, spacing=0.03, distribution=distribution),
                       np.random.default_rng(3))
    assert len(drips.positions) == 40
    assert pdist(drips.positions).min() >= 0.03
    # a region too small for the count gives fewer points, still spaced
    crowded = find_drips(sphere, water, G, DripOptions(200, 30.0, spacing=0.03, distribution=distribution),
                         np.random.default_rng(3))
    assert 1 <= len(crowded.positions) < 60
    assert pdist(crowded.positions).min() >= 0.03


def test_area_without_spacing_is_the_papers_spread(sphere):
    water = compute_water(sphere, G, RainOptions(4000, 0.01), np.random.default_rng(2)).water
    drips = find_drips(sphere, water, G, DripOptions(30, 60.0, spacing=0.0, distribution="area"),
                       np.random.default_rng(5))
    region = drip_region(sphere, water, G, 60.0)
    points, face, _ = sample_faces(sphere, region, 60, np.random.default_rng(5))
    np.testing.assert_array_equal(drips.positions, points[:30])
    np.testing.assert_array_equal(drips.faces, face[:30])


def test_water_drips_from_the_rim_not_the_underside(wet_umbrella):
    mesh, water = wet_umbrella
    by_water = umbrella_drips(mesh, water, "water")
    by_area = umbrella_drips(mesh, water, "area")
    assert len(by_water.positions) == len(by_area.positions) == 40
    # the rim is the underside's lowest edge (the wet part of the region hugs it): water
    # puts the points lower, on it
    assert by_water.positions[:, 1].mean() < by_area.positions[:, 1].mean() - 0.002
    assert rim_distance(by_water.positions).max() < 0.002
    assert rim_distance(by_water.positions).mean() < 0.5 * rim_distance(by_area.positions).mean()
    assert (by_water.water > 0).all()
    # every point still lies on the drip region
    assert np.isin(by_water.faces, by_water.region_faces).all()


def test_a_sharp_lip_sheds_its_water_and_a_dome_its_whole_cap(sphere, wet_umbrella):
    mesh, water = wet_umbrella
    region = drip_region(mesh, water, G, 75.0, off_the_ground(mesh))
    flux = drip_flux(mesh, water, G, 75.0, region)
    shed = flux > 0
    assert (rim_distance(mesh.vertices[shed]) < 0.01).all()
    # a dome sheds as the paper spreads: over its whole cap, not at one ring
    water = compute_water(sphere, G, RainOptions(4000, 0.01), np.random.default_rng(2)).water
    flux = drip_flux(sphere, water, G, 75.0, drip_region(sphere, water, G, 75.0))
    heights = sphere.vertices[flux > 0, 1]
    assert np.ptp(heights) > 0.1


def test_more_water_longer_icicles(wet_umbrella):
    mesh, water = wet_umbrella
    once = umbrella_drips(mesh, water, "water")
    twice = umbrella_drips(mesh, 2 * water, "water")
    np.testing.assert_allclose(twice.positions, once.positions)
    np.testing.assert_allclose(twice.water, 2 * once.water)
    # two umbrellas, one twice as wet: its icicles get more water and grow longer
    pair = trimesh.util.concatenate([mesh, umbrella((1.0, 0.0, 0.0))])
    wet = np.r_[water, 2 * water]
    options = DripOptions(60, 75.0, spacing=0.025, distribution="water", exclude_vertices=off_the_ground(pair))
    drips = find_drips(pair, wet, G, options, np.random.default_rng(4))
    second = drips.positions[:, 0] > 0.5
    assert 10 <= second.sum() <= 50
    assert drips.water[second].mean() > 1.5 * drips.water[~second].mean()
    straight = dataclasses.replace(DEFAULTS.trajectories, curve_angle=0.0, division_probability=0.0)
    traj = grow_trajectories(pair, drips.positions, drips.normals, drips.water, np.random.default_rng(0),
                             trajectory_options(straight, G, 75.0))
    trunks = np.flatnonzero(traj.branch_parent == -1)
    length = np.array([np.linalg.norm(np.diff(traj.branch(b), axis=0), axis=1).sum() for b in trunks])
    icicle_of = traj.branch_icicle[trunks]
    assert length[second[icicle_of]].mean() > 1.5 * length[~second[icicle_of]].mean()
    order = np.argsort(drips.water[icicle_of])
    assert (np.diff(length[order]) >= -1e-9).all(), "more water never gives a shorter trunk"


def test_fountain_icicles_hang_from_the_upper_bowls_lip():
    # the acceptance run: generator:fountain --size-m 0.6, water.pools=overflow,
    # drips.ground_clearance=0.3, drips.count=32, the default spacing and distribution
    size = 0.6
    prepared = prepare(generate("fountain"), size, G)
    mesh = prepared.mesh
    water = compute_water(mesh, G, RainOptions(4000, 0.01, "overflow"), np.random.default_rng(0)).water
    ground = off_the_ground(mesh, 0.3)
    results = {}
    for distribution in ("water", "area"):
        options = DripOptions(32, 75.0, spacing=0.025, distribution=distribution, exclude_vertices=ground)
        drips = find_drips(mesh, water, G, options, np.random.default_rng(1))
        # the lip: (r, y) = (0.58, 1.00) to (0.56, 0.97) in the profile's units, 1.17 tall
        scale = size / 1.17
        points = drips.positions + prepared.offset
        r, y = np.hypot(points[:, 0], points[:, 2]) / scale, points[:, 1] / scale
        a, b = np.array([0.56, 0.97]), np.array([0.58, 1.00])
        rel = np.c_[r, y] - a
        t = np.clip(rel @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        near = np.linalg.norm(rel - t[:, None] * (b - a), axis=1) * scale < 0.02
        results[distribution] = (near.mean(), drips.water.std() / drips.water.mean(), len(drips.positions))
    near, spread, count = results["water"]
    assert count == 32 and near >= 0.8 and spread >= 0.3
    assert results["area"][0] < 0.5 and results["area"][1] < 0.3  # the paper's spread: all over, alike


# ------------------------------------------------------------------------------ coarse meshes

def table_boxes() -> list[trimesh.Trimesh]:
    """A box-modelled table 0.8 tall: a 1.2 x 0.05 x 0.8 top on four 0.06 wide legs."""
    move = trimesh.transformations.translation_matrix
    return [trimesh.creation.box(extents=(1.2, 0.05, 0.8), transform=move((0, 0.775, 0))),
            *[trimesh.creation.box(extents=(0.06, 0.76, 0.06), transform=move((x, 0.38, z)))
              for x in (-0.52, 0.52) for z in (-0.32, 0.32)]]


def test_coarse_meshes_are_refined_and_dense_ones_left_alone(sphere):
    cylinder = trimesh.creation.cylinder(radius=0.3, height=0.1, sections=10)
    problems = detect_problems(cylinder)
    assert "coarse" in proxy_reason(problems, "auto", DEFAULTS.proxy.face_budget)
    assert proxy_reason(problems, "never", DEFAULTS.proxy.face_budget) is None
    assert proxy_reason(detect_problems(sphere), "auto", DEFAULTS.proxy.face_budget) is None
    assert proxy_reason(detect_problems(generate("fountain")), "auto", DEFAULTS.proxy.face_budget) is None
    proxy = build_proxy(cylinder, DEFAULTS.proxy, problems)
    assert proxy.method is ProxyMethod.REFINE and proxy.mesh.is_watertight
    assert proxy.faces > 4 * len(cylinder.faces)
    # refining keeps the shape: every proxy vertex lies on the cylinder
    _, distance, _ = trimesh.proximity.closest_point(cylinder, proxy.mesh.vertices)
    assert distance.max() < 1e-6


@pytest.mark.parametrize("loose", [False, True], ids=["welded", "loose-boxes"])
def test_low_poly_table_gets_icicles_along_its_tops_rim(tmp_path, loose):
    # welded: one clean coarse manifold, refined; loose: the boxes merely stacked (loose,
    # intersecting parts), wrapped
    boxes = table_boxes()
    table = trimesh.util.concatenate(boxes) if loose else trimesh.boolean.union(boxes, engine="manifold")
    assert len(table.faces) < 100
    path = tmp_path / "table.obj"
    table.export(path)
    # a flow mesh of 5 cm edges (25 mm by default): the same 115-118 drip points, all on the rim
    spec = JobSpec("table", str(path), 0.8, params.resolve({"storm.flow_edge": 0.05}), seed=0)
    outcome = run_job(spec, tmp_path / "job", until=Stage.TRAJECTORIES)
    assert outcome.status == "done", outcome.error
    done = json.loads((tmp_path / "job" / "done.json").read_text())
    assert "coarse" in done["proxy_reason"]
    drips = json.loads((tmp_path / "job" / "drips.json").read_text())["drip_points"]
    points = np.array([d["position"] for d in drips])
    assert len(points) >= 16
    # the object is centred on its bounding box: the top's underside lies at y = 0.35, its
    # rim at |x| = 0.6 or |z| = 0.4
    on_rim = (np.abs(points[:, 1] - 0.35) < 0.02) & (
        (np.abs(np.abs(points[:, 0]) - 0.6) < 0.02) | (np.abs(np.abs(points[:, 2]) - 0.4) < 0.02))
    assert on_rim.mean() >= 0.8
    icicles = json.loads((tmp_path / "job" / "trajectories.json").read_text())["icicles"]
    trunks = [np.asarray(b["points"]) for ic in icicles for b in ic["branches"] if b["parent"] == -1]
    lengths = [np.linalg.norm(np.diff(t, axis=0), axis=1).sum() for t in trunks]
    assert np.median(lengths) >= 0.02


@pytest.mark.parametrize("distribution", ["water", "area"])
def test_no_drip_point_without_room_to_hang(wet_umbrella, distribution):
    """drips.min_fall: the umbrella's rim is 0.30 above its foot, so a floor 0.25 below the
    rim leaves room and one 0.02 below it none; every kept point has the room asked."""
    mesh, water = wet_umbrella
    rng = lambda: np.random.default_rng(4)  # noqa: E731
    kwargs = dict(spacing=0.025, distribution=distribution, exclude_vertices=off_the_ground(mesh))
    free = find_drips(mesh, water, G, DripOptions(20, 75.0, **kwargs), rng())
    room = find_drips(mesh, water, G, DripOptions(20, 75.0, min_fall=0.1, floor=0.05, **kwargs), rng())
    none = find_drips(mesh, water, G, DripOptions(20, 75.0, min_fall=0.1, floor=0.28, **kwargs), rng())
    assert len(free.positions) > 5 and len(room.positions) > 5
    assert (room.positions[:, 1] - 0.05 >= 0.1).all()
    assert len(none.positions) == 0


def test_dry_drip_points_grow_no_icicle(wet_umbrella):
    """drips.min_length (as min_water): points whose water would grow an icicle shorter than
    asked are dropped; the rest keep at least that much water."""
    mesh, water = wet_umbrella
    every = umbrella_drips(mesh, water, "water")
    threshold = float(np.quantile(every.water, 0.5))
    options = DripOptions(40, 75.0, spacing=0.025, distribution="water", exclude_vertices=off_the_ground(mesh),
                          min_water=threshold)
    wet = find_drips(mesh, water, G, options, np.random.default_rng(3))
    assert 0 < len(wet.positions) < len(every.positions)
    assert (wet.water >= threshold).all()


def _spaced_reference(points, spacing, count):
    """Dart throwing compared with every kept point: what `spaced`'s compiled grid must give."""
    kept: list[int] = []
    for i, p in enumerate(points):
        if len(kept) == count:
            break
        if not kept or (((points[kept] - p) ** 2).sum(axis=1) >= spacing**2).all():
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)


@pytest.mark.parametrize("spacing, count", [(0.05, 10_000), (0.2, 40), (0.013, 10_000), (0.5, 1)])
def test_dart_throwing_keeps_the_first_points_far_enough_apart(spacing, count):
    from icefarm.stages.dart_throwing import spaced

    rng = np.random.default_rng(5)
    # a thin slab over negative and positive cells, with points exactly on cell planes
    points = rng.uniform(-1, 1, (3000, 3)) * np.array([1.0, 0.02, 1.0])
    points[:200] = np.round(points[:200] / spacing) * spacing
    got = spaced(points, spacing, count)
    np.testing.assert_array_equal(got, _spaced_reference(points, spacing, count))
    assert len(got) <= count and (len(got) < 2 or pdist(points[got]).min() >= spacing)
