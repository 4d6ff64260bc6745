"""Properties of stages 1-3 (paper 4.1-4.3)."""

import numpy as np
import pytest
import trimesh

from icefarm.mesh import prepare
from icefarm.stages.basins import overflow_heights, spill_levels, spill_over, spill_routes
from icefarm.stages.drips import DripOptions, find_drips
from icefarm.stages.trajectories import GOLDEN_ROLL, TrajectoryOptions, grow_trajectories
from icefarm.stages.water import RainOptions, compute_water, water_coefficients

G = np.array([0.0, -1.0, 0.0])
TRAJ = dict(curve_angle=2.0, division_probability=0.1, roll_angle=360.0, step_length=0.004,
            length_scale=0.6, max_branches=32, drip_limit=75.0)


def reference_water(mesh, supply, g):
    """Algorithm 1 as the paper writes it: one walk per vertex, a Python loop."""
    neighbours = mesh.vertex_neighbors
    wc = np.zeros(len(mesh.vertices))
    for v in range(len(mesh.vertices)):
        c, total = v, 0.0
        while True:
            best, best_p = None, 0.0
            for n in neighbours[c]:
                cn = mesh.vertices[n] - mesh.vertices[c]
                p = cn @ g / np.linalg.norm(cn)
                if p < best_p:
                    best, best_p = n, p
            if best is None:
                break
            if supply[c] or supply[best]:
                gain = np.linalg.norm(mesh.vertices[best] - mesh.vertices[c]) * -best_p
                total += gain if supply[c] and supply[best] else gain / 2
            c = best
        wc[v] = total
    return wc


def test_water_matches_algorithm_1(rng):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    mesh.vertices += rng.normal(scale=0.004, size=mesh.vertices.shape)  # no ties between neighbours
    supply = rng.random(len(mesh.vertices)) < 0.4
    water, top, d_up, _, _ = water_coefficients(mesh, supply, G)
    np.testing.assert_allclose(water, reference_water(mesh, supply, G), atol=1e-12)
    # every walk ends at a vertex with no higher neighbour
    for v in np.unique(top):
        assert all(mesh.vertices[n] @ G >= mesh.vertices[v] @ G for n in mesh.vertex_neighbors[v])
    assert (d_up >= 0).all()


def cup() -> trimesh.Trimesh:
    """A closed 20 cm cup with a 1 cm rim wall: a basin 8 cm deep (floor 0.10, rim 0.18), y up."""
    profile = np.array([[0.0, 0.0], [0.10, 0.0], [0.10, 0.18], [0.09, 0.18], [0.09, 0.10], [0.0, 0.10]])
    mesh = trimesh.creation.revolve(profile, sections=48)  # about +z
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))  # z -> y up
    return trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, 0.02))


def test_spill_levels_are_the_lowest_pass_to_an_outlet():
    heights = np.array([0.0, 2.0, 1.0, 3.0, 0.5])  # a path 0-1-2-3, vertex 4 hangs off 2
    edges = np.array([[0, 1], [1, 2], [2, 3], [2, 4]])
    outlets = np.array([True, False, False, False, False])
    np.testing.assert_array_equal(spill_levels(heights, edges, outlets), [0.0, 2.0, 2.0, 3.0, 2.0])
    assert np.isinf(spill_levels(heights, edges[:1], outlets)[2])  # cut off from every outlet


def test_a_full_cup_spills_its_depth_over_its_rim():
    mesh = cup()
    supply = mesh.vertex_normals @ G < -0.5  # rain on everything facing up
    bonus = overflow_heights(mesh, supply, G)
    y = mesh.vertices[:, 1]
    rim = bonus > 0
    assert rim.any() and np.allclose(y[rim], 0.18, atol=1e-9)  # only the rim top
    np.testing.assert_allclose(bonus[rim], 0.08, atol=1e-9)  # the basin's depth
    assert np.all(bonus[np.abs(y - 0.18) > 1e-6] == 0)
    assert not overflow_heights(mesh, np.zeros(len(y), bool), G).any()  # no rain in it, nothing spills
    # Walks up the outer wall end on the rim and carry the cup's water; the paper's
    # Algorithm 1 (pools ignored) is unchanged.
    plain = compute_water(mesh, G, RainOptions(3000, 0.01), np.random.default_rng(0))
    spilled = compute_water(mesh, G, RainOptions(3000, 0.01, "overflow"), np.random.default_rng(0))
    np.testing.assert_array_equal(spilled.supply, plain.supply)
    outer_wall = (np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 2]) > 0.0999) & (y > 0.01) & (y < 0.17)
    np.testing.assert_allclose(spilled.water[outer_wall] - plain.water[outer_wall], 0.08, atol=1e-9)


def test_a_tilted_cup_spills_at_its_lowest_rim_point_and_a_ball_holds_nothing(sphere):
    mesh = cup()
    radius = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 2])
    inner_rim = np.flatnonzero(np.isclose(mesh.vertices[:, 1], 0.18) & np.isclose(radius, 0.09))
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(10.0), (0, 0, 1)))
    bonus = overflow_heights(mesh, mesh.vertex_normals @ G < -0.5, G)
    lowest = inner_rim[np.argmin(mesh.vertices[inner_rim, 1])]
    assert np.flatnonzero(bonus) == [lowest]  # water leaves over the lowest point of the lip
    assert bonus[lowest] == pytest.approx(0.08 * np.cos(np.radians(10.0)))  # lip to the floor's low edge
    assert not overflow_heights(sphere, np.ones(len(sphere.vertices), bool), G).any()  # nowhere to pool


def test_a_full_cup_spills_all_round_a_level_lip_and_at_the_low_point_of_a_tilted_one():
    mesh = cup()
    routes = spill_routes(mesh, G)
    angle = np.arctan2(mesh.vertices[routes.target, 2], mesh.vertices[routes.target, 0])
    assert np.all(np.hypot(mesh.vertices[routes.target, 0], mesh.vertices[routes.target, 2]) > 0.0995)  # outside
    assert np.ptp(np.sort(angle)) > 1.9 * np.pi and np.diff(np.sort(angle)).max() < 0.3  # all round
    pooled = np.where(routes.basin >= 0, 1e-6, 0.0)
    spilled, kept = spill_over(pooled, routes)
    assert spilled.sum() == pytest.approx(pooled.sum()) and not kept.any()
    top = np.flatnonzero(np.isclose(mesh.vertices[:, 1], 0.18))
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(10.0), (0, 0, 1)))
    tilted = spill_routes(mesh, G)
    low = mesh.vertices[top[np.argmin(mesh.vertices[top, 1])]]
    assert len(tilted.target) and np.linalg.norm(mesh.vertices[tilted.target] - low, axis=1).max() < 0.02  # the notch
    assert spill_routes(trimesh.creation.icosphere(3), G).target.size == 0  # nothing to spill from


def test_water_dripping_clear_of_the_object_leaves_it():
    """An arch whose left foot stands 2 cm higher, on a shoe: its water drips off the sole.

    Were only the lowest point an outlet, the left leg would hold water up to the beam
    (0.18 m deep over the shoe's rained-on top) and spill it there.
    """
    def box(lo, hi):
        b = trimesh.creation.box(extents=np.subtract(hi, lo))
        b.apply_translation(np.add(lo, hi) / 2)
        return b

    parts = [box((-0.10, 0.02, -0.03), (-0.06, 0.22, 0.03)), box((-0.13, 0.02, -0.03), (-0.03, 0.04, 0.03)),
             box((0.06, 0.0, -0.03), (0.10, 0.22, 0.03)), box((-0.10, 0.20, -0.03), (0.10, 0.24, 0.03))]
    arch = trimesh.boolean.union(parts, engine="manifold")
    arch = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(arch.vertices, arch.faces, 0.01))
    assert not overflow_heights(arch, arch.vertex_normals @ G < -0.5, G).any()


def test_water_only_where_walk_reaches_supply(sphere, rng):
    result = compute_water(sphere, G, RainOptions(2000, 0.01), rng)
    assert result.supply.any() and not result.supply.all()
    up_normals = sphere.vertex_normals @ G < 0
    assert not (result.supply & ~up_normals).any(), "supply vertices must face against gravity"
    # water > 0 exactly where the upward walk touches a supply vertex
    neighbours = sphere.vertex_neighbors
    for v in rng.choice(len(sphere.vertices), 120, replace=False):
        c, touches = v, False
        while True:
            higher = [n for n in neighbours[c] if (sphere.vertices[n] - sphere.vertices[c]) @ G < 0]
            if not higher:
                break
            n = min(higher, key=lambda n: (sphere.vertices[n] - sphere.vertices[c]) @ G
                    / np.linalg.norm(sphere.vertices[n] - sphere.vertices[c]))
            touches |= bool(result.supply[c] or result.supply[n])
            c = n
        assert (result.water[v] > 0) == touches


def test_overhang_shadows_the_supply(sphere):
    plate = trimesh.creation.box(extents=(0.12, 0.01, 0.12))
    plate.apply_translation((0, 0.25, 0))
    both = trimesh.util.concatenate([sphere, plate])
    under = np.flatnonzero((np.linalg.norm(sphere.vertices[:, [0, 2]], axis=1) < 0.03)
                           & (sphere.vertices[:, 1] > 0))
    open_sky = compute_water(sphere, G, RainOptions(20000, 0.01), np.random.default_rng(1))
    shaded = compute_water(both, G, RainOptions(20000, 0.01), np.random.default_rng(1))
    assert open_sky.supply[under].all()
    assert not shaded.supply[under].any()
    assert shaded.supply[len(sphere.vertices):].any(), "the plate's top is wet"


@pytest.mark.parametrize("drip_limit", [20.0, 45.0, 75.0])
def test_every_drip_point_within_drip_limit(sphere, drip_limit):
    water = compute_water(sphere, G, RainOptions(4000, 0.01), np.random.default_rng(2))
    drips = find_drips(sphere, water.water, G, DripOptions(50, drip_limit), np.random.default_rng(3))
    assert len(drips.positions) == 50
    angles = np.degrees(np.arccos(np.clip(drips.normals @ G, -1, 1)))
    assert (angles <= drip_limit + 1e-9).all()
    vertex_angles = np.degrees(np.arccos(np.clip(sphere.vertex_normals[sphere.faces[drips.faces]] @ G, -1, 1)))
    assert (vertex_angles <= drip_limit + 1e-9).all()
    assert (drips.water > 0).all()


def test_coarse_mesh_drips_on_transition(rng):
    coarse = trimesh.creation.icosphere(subdivisions=0, radius=0.15)
    # one vertex 10 degrees off straight down: its faces' other corners are ~60 degrees off
    down = trimesh.geometry.align_vectors(coarse.vertices[0], G)
    tilt = trimesh.transformations.rotation_matrix(np.radians(10), (1, 0, 0))
    coarse.apply_transform(tilt @ down)
    water = np.ones(len(coarse.vertices))
    drips = find_drips(coarse, water, G, DripOptions(5, 20.0), rng)
    assert len(drips.region_faces) == 0
    assert len(drips.positions) >= 1
    assert (np.degrees(np.arccos(drips.normals @ G)) <= 20.0 + 1e-9).all()


def test_exclusion_box_keeps_icicles_off(sphere, rng):
    water = compute_water(sphere, G, RainOptions(4000, 0.01), rng)
    box = ((-1.0, -1.0, -1.0), (0.0, 1.0, 1.0))
    drips = find_drips(sphere, water.water, G, DripOptions(60, 75.0, exclude_boxes=[box]), rng)
    assert (drips.positions[:, 0] > 0).all()


def grow(mesh, drips, seed=0, **overrides):
    return grow_trajectories(mesh, drips.positions, mesh.face_normals[drips.faces], drips.water,
                             np.random.default_rng(seed), TrajectoryOptions(gravity=G, **{**TRAJ, **overrides}))


@pytest.fixture
def sphere_drips(sphere):
    water = compute_water(sphere, G, RainOptions(4000, 0.01), np.random.default_rng(2))
    return find_drips(sphere, water.water, G, DripOptions(30, 60.0), np.random.default_rng(3))


def test_straight_icicles_when_c_and_d_are_zero(sphere, sphere_drips):
    traj = grow(sphere, sphere_drips, curve_angle=0.0, division_probability=0.0)
    assert traj.n_branches == len(sphere_drips.positions)
    assert (traj.branch_parent == -1).all()
    for b in range(traj.n_branches):
        pts = traj.branch(b)
        assert len(pts) >= 2
        np.testing.assert_allclose(pts[:, [0, 2]] - pts[0, [0, 2]], 0.0, atol=1e-12)
        assert (np.diff(pts[:, 1]) < 0).all()


def lsystem_branches(generations: int) -> int:
    """Branches of the paper's L-system with d = 1, by rewriting the string."""
    word = "FX"
    for _ in range(generations):
        word = "".join({"X": "[+F-FX]A", "A": "+FFF/X"}.get(ch, ch) for ch in word)
    return word.count("[")


def test_full_division_branches_every_generation_at_30_degrees():
    mesh = trimesh.creation.box(extents=(0.1, 0.02, 0.1))
    start = np.array([[0.0, -0.01, 0.0]])
    gens = 5
    # branch_spread = 0: the paper's p1'' exactly, one F at 30 degrees
    options = TrajectoryOptions(gravity=G, **{**TRAJ, "curve_angle": 0.0, "branch_spread": 0.0,
                                              "division_probability": 1.0, "max_branches": 1000})
    traj = grow_trajectories(mesh, start, [[0, -1, 0]], [0.004 * (1 + 3 * gens) / 0.6], np.random.default_rng(0),
                             options)
    assert traj.n_branches - 1 == lsystem_branches(gens)
    for b in np.flatnonzero(traj.branch_parent >= 0):
        pts = traj.branch(b)
        first = (pts[1] - pts[0]) / np.linalg.norm(pts[1] - pts[0])
        second = (pts[2] - pts[1]) / np.linalg.norm(pts[2] - pts[1])
        assert np.degrees(np.arccos(np.clip(first @ G, -1, 1))) == pytest.approx(30.0, abs=1e-6)
        np.testing.assert_allclose(second, G, atol=1e-9)  # then parallel to the (straight) parent


@pytest.mark.parametrize("roll_angle", [0.0, 90.0, 360.0])
def test_roll_follows_au(roll_angle):
    mesh = trimesh.creation.box(extents=(0.1, 0.02, 0.1))
    options = TrajectoryOptions(gravity=G, **{**TRAJ, "curve_angle": 0.0, "roll_angle": roll_angle,
                                              "division_probability": 1.0, "max_branches": 1000})
    traj = grow_trajectories(mesh, np.array([[0.0, -0.01, 0.0]]), [[0, -1, 0]], [0.5], np.random.default_rng(0),
                             options)
    trunk_children = np.flatnonzero(traj.branch_parent == 0)
    assert len(trunk_children) >= 4
    out = np.array([traj.branch(b)[1] - traj.branch(b)[0] for b in trunk_children])
    azimuth = np.degrees(np.arctan2(out[:, 2], out[:, 0]))
    steps = np.mod(np.diff(azimuth), 360.0)
    expected = roll_angle * GOLDEN_ROLL / 360.0
    np.testing.assert_allclose(np.minimum(steps, 360 - steps), min(expected, 360 - expected), atol=1e-6)


def test_trajectories_are_seeded(sphere, sphere_drips):
    a = grow(sphere, sphere_drips, seed=5, division_probability=0.5)
    b = grow(sphere, sphere_drips, seed=5, division_probability=0.5)
    c = grow(sphere, sphere_drips, seed=6, division_probability=0.5)
    np.testing.assert_array_equal(a.points, b.points)
    assert a.points.shape != c.points.shape or not np.array_equal(a.points, c.points)


def crossing_segments(mesh, traj) -> int:
    starts, ends = [], []
    for b in range(traj.n_branches):
        pts = traj.branch(b)
        starts.append(pts[:-1])
        ends.append(pts[1:])
    a, b = np.concatenate(starts), np.concatenate(ends)
    length = np.linalg.norm(b - a, axis=1)
    loc, ray, _ = mesh.ray.intersects_location(a, (b - a) / length[:, None], multiple_hits=False)
    return int((np.linalg.norm(loc - a[ray], axis=1) < length[ray]).sum())


@pytest.mark.slow  # reads ../shared/meshes
@pytest.mark.parametrize("name", ["cow.obj", "teapot.obj", "stanford-bunny.obj"])
def test_no_trajectory_enters_the_object(shared_mesh, name):
    mesh = prepare(shared_mesh(name), 0.3).mesh
    water = compute_water(mesh, G, RainOptions(4000, 0.01), np.random.default_rng(0))
    drips = find_drips(mesh, water.water, G, DripOptions(120, 75.0), np.random.default_rng(1))
    traj = grow(mesh, drips, curve_angle=8.0, division_probability=0.3)
    assert traj.n_branches >= len(drips.positions) > 50
    if mesh.is_watertight:
        assert not mesh.contains(traj.points).any()
    assert crossing_segments(mesh, traj) == 0
    # every icicle hangs: its lowest point lies below its drip point
    for b in np.flatnonzero(traj.branch_parent == -1):
        pts = traj.branch(b)
        assert pts[:, 1].min() < pts[0, 1]
