"""A fringe of icicles along a rim (icefarm.stages.rims.compete and swallow, the heat-limited
length of icefarm.stages.icicle_size) and how it is measured (icefarm.stages.surface.fringe):
a few long icicles with short ones between them, each hanging free of its neighbours."""

import numpy as np
import pytest
import trimesh

from icefarm import params
from icefarm.stages.icicle_size import IcicleSizing, heat_limited_length, icicle_lengths
from icefarm.stages.rims import compete, swallow
from icefarm.stages.surface.fringe import hangs_free, length_contrast, trunk_lengths
from icefarm.stages.trajectories import TrajectoryResult

G = np.array([0.0, -1.0, 0.0])


def _rim(count=80, spacing=0.025):
    """Drip points every ``spacing`` along a straight, evenly wet eave."""
    return np.column_stack([np.arange(count) * spacing, np.zeros(count), np.zeros(count)])


def _sizing(**storm):
    p = params.resolve({f"storm.{k}": v for k, v in storm.items()})
    return IcicleSizing(p.storm, p.surface)


def test_competing_icicles_keep_the_water_and_grow_a_ragged_fringe():
    rim = _rim()
    even = np.full(len(rim), 2e-4)  # m^3 each stretch sheds: about 20 cm icicles, all alike
    water, active = compete(even, rim, np.random.default_rng(3), 0.025)
    assert water.sum() == pytest.approx(even.sum())
    assert (active >= 0).all() and (active <= 1).all()
    sizing = _sizing()
    assert length_contrast(rim, sizing.length(even)) == pytest.approx(1.0)
    assert length_contrast(rim, sizing.length(water, active)) >= 2.5
    # the same seed, the same fringe
    again, _ = compete(even, rim, np.random.default_rng(3), 0.025)
    assert np.array_equal(water, again)


def test_a_drip_point_under_a_bigger_icicle_feeds_it():
    rim = _rim(40)
    water, active = compete(np.full(len(rim), 2e-4), rim, np.random.default_rng(1), 0.025)
    sizing = _sizing()
    kept_water, kept_active, kept = swallow(water, active, rim, sizing, G)
    assert kept_water.sum() == pytest.approx(water.sum()) and (~kept).any()
    assert (kept_water[~kept] == 0).all()
    length = sizing.length(kept_water, kept_active)
    idx = np.flatnonzero(kept)
    for a in idx:  # no two kept icicles touch at half the shorter one's length
        for b in idx[idx > a]:
            depth = 0.5 * min(length[a], length[b])
            gap = (np.linalg.norm(rim[a] - rim[b]) - sizing.radius(length[[a]], kept_active[[a]], [depth])[0]
                   - sizing.radius(length[[b]], kept_active[[b]], [depth])[0])
            assert gap >= 0.0


def test_the_storm_s_cold_limits_how_long_an_icicle_grows():
    p = params.resolve({})
    light, moderate, severe = (heat_limited_length(params.resolve({"storm.intensity": i}).storm, p.surface)[0]
                               for i in ("light", "moderate", "severe"))
    assert 0.1 < light < moderate < severe < 1.5
    melt = [heat_limited_length(params.resolve({"storm.kind": "meltwater", "storm.intensity": i}).storm,
                                p.surface)[0] for i in ("light", "moderate", "severe")]
    # nights of frost: a light snow's icicles get a moderate storm's cold (a thinner base, a
    # little longer)
    assert melt[0] == pytest.approx(melt[1], rel=0.05) and moderate < melt[1] < melt[2]
    water = np.geomspace(1e-6, 1e-1, 60)  # m^3 reaching one drip point
    length = icicle_lengths(water, p.storm, p.surface)
    assert length.max() <= moderate + 1e-9
    top = int(np.argmax(length))
    assert np.all(np.diff(length[:top + 1]) >= 0)  # more water, longer, up to the cold's limit
    assert np.all(np.diff(length[top:]) <= 1e-12)  # then its warmth slows the lengthening


def _tube(x, length, radius, sections=24):
    """A closed cylinder hanging ``length`` from (x, 0, 0)."""
    tube = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    tube.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    tube.apply_translation([x, -length / 2, 0])
    return tube


def _trunks(xs, lengths):
    points, offsets = [], [0]
    for x, L in zip(xs, lengths):
        points += [[x, -d, 0.0] for d in np.linspace(0.0, L, 9)]
        offsets.append(len(points))
    n = len(xs)
    return TrajectoryResult(points=np.asarray(points), branch_offsets=np.asarray(offsets),
                            branch_icicle=np.arange(n), branch_parent=np.full(n, -1))


def test_icicles_apart_hang_free_and_fused_ones_do_not():
    traj = _trunks([0.0, 0.05, 0.08], [0.2, 0.1, 0.1])
    apart = trimesh.util.concatenate([_tube(0.0, 0.2, 0.008), _tube(0.05, 0.1, 0.006), _tube(0.08, 0.1, 0.006)])
    trunks, free = hangs_free(apart.vertices, apart.faces, traj, G)
    assert len(trunks) == 3 and free.all()
    # the last two grown into one sheet: one loop around both axes
    sheet = trimesh.creation.box([0.05, 0.1, 0.012])
    sheet.apply_translation([0.065, -0.05, 0.0])
    fused = trimesh.util.concatenate([_tube(0.0, 0.2, 0.008), sheet])
    _, free = hangs_free(fused.vertices, fused.faces, traj, G)
    assert free.tolist() == [True, False, False]


def test_length_contrast_reads_an_even_fringe_as_even():
    rim = _rim(20)
    assert length_contrast(rim, np.full(20, 0.2)) == pytest.approx(1.0)
    ragged = np.where(np.arange(20) % 4 == 0, 0.3, 0.05)
    assert length_contrast(rim, ragged) == pytest.approx(6.0)
    # roots farther apart than the reach have no neighbours to compare with
    assert np.isnan(length_contrast(rim[:2] * 10, np.array([0.1, 0.3])))
    traj = _trunks([0.0, 0.1], [0.2, 0.05])
    _, lengths = trunk_lengths(traj)
    assert lengths == pytest.approx([0.2, 0.05])


def test_the_default_storm_blows_from_the_asset_s_front_and_still_air_is_one_setting():
    assert params.resolve({}).storm.wind == pytest.approx((0.0, 0.0, -3.0))
    assert params.resolve({"water.gravity": [0, 0, -1]}).storm.wind == pytest.approx((0.0, 3.0, 0.0))
    assert params.resolve({"storm.wind": "0,0,0"}).storm.wind == pytest.approx((0.0, 0.0, 0.0))
    # a job's own params.yaml, read back, keeps its wind
    p = params.resolve({"storm.wind": [1.0, 0.0, 0.0]})
    assert params.resolve(p).storm.wind == pytest.approx((1.0, 0.0, 0.0))


def test_a_street_sign_in_the_default_breeze_glazes_its_windward_face_and_drips_under_its_plate():
    from icefarm.generators import generate, natural_size
    from icefarm.job import Stage, run_stages
    from icefarm.mesh import prepare

    prep = prepare(generate("sign"), natural_size("sign"))
    r = run_stages(prep, params.resolve({}), 3, until=Stage.DRIPS)
    flow = r.flow
    bottom = 1.6 - natural_size("sign") / 2  # the plate's lower edge, the mesh centred on the origin
    plate = flow.vertices[:, 1] > bottom + 0.02
    normals = np.asarray(flow.vertex_normals)
    windward, lee = plate & (normals[:, 2] > 0.9), plate & (normals[:, 2] < -0.9)
    ice = r.water.storm.ice
    assert np.median(ice[windward]) > 0.002 and np.median(ice[lee]) == 0.0
    under = np.abs(r.drips.positions[:, 1] - bottom) < 0.01
    assert under.sum() >= 10
    still = run_stages(prep, params.resolve({"storm.wind": "0,0,0"}), 3, until=Stage.DRIPS)
    assert (np.abs(still.drips.positions[:, 1] - bottom) < 0.01).sum() < under.sum()


def test_no_icicle_hangs_glued_to_a_leg_under_its_rim():
    from icefarm.spatial import ray_caster
    from icefarm.stages.drips import side_room

    seat = trimesh.creation.box([1.0, 0.04, 0.4])
    leg = trimesh.creation.box([0.05, 0.5, 0.05])
    leg.apply_translation([0.0, -0.27, 0.175])  # flush with the seat's front edge (z = 0.2)
    mesh = trimesh.util.concatenate([seat, leg])
    rim = np.array([[0.0, -0.02, 0.2], [0.02, -0.02, 0.2], [0.3, -0.02, 0.2]])  # beside the leg, at it, clear
    room = side_room(ray_caster(mesh), mesh.face_normals, rim, G, 0.025)
    assert room.tolist() == [False, False, True]
    # a ray that starts inside the object is not counted: a point under a thick seat's rim
    assert side_room(ray_caster(mesh), mesh.face_normals, np.array([[0.3, 0.0, 0.19]]), G, 0.01).all()


def test_an_icicle_stops_short_of_what_lies_below_it():
    """A severe storm's winners under a 0.74 m garden table would reach the ground and be cut
    into pillars; they stop short of it, the rest of their water dripping down."""
    from icefarm.generators import generate, natural_size
    from icefarm.job import Stage, run_stages
    from icefarm.mesh import prepare

    prep = prepare(generate("table"), natural_size("table"))
    r = run_stages(prep, params.resolve({"storm.intensity": "severe"}), 3, until=Stage.TRAJECTORIES)
    trunks = r.trajectories.branch_parent < 0
    assert trunks.sum() >= 10
    assert not r.trajectories.cut[trunks].any()  # none reached the ground
    _, lengths = trunk_lengths(r.trajectories)
    assert lengths.max() > 0.3  # the winners still grow long


def test_the_icicles_the_cold_limits_are_not_all_one_length():
    # A meltwater eave's winners all reached the heat limit and hung as an even comb; each
    # icicle's share of the cold (exposure, start) varies, and so does its limit.
    sizing = _sizing(kind="meltwater")
    flood = np.full(5, 1e-2)  # far more water than any of them can freeze
    alike = sizing.length(flood, np.ones(5))
    assert np.ptp(alike) == pytest.approx(0.0)
    exposure = np.array([0.5, 0.8, 1.0, 1.25, 2.0])
    varied = sizing.length(flood, np.ones(5), exposure)
    assert (np.diff(varied) > 0).all() and varied[-1] / varied[0] > 2.5
    assert varied[2] == pytest.approx(alike[2])
    short = np.full(5, 1e-6)  # icicles their water limits keep their length
    assert np.allclose(sizing.length(short, np.ones(5), exposure), sizing.length(short, np.ones(5)))


def test_the_faces_a_level_cuts_near_a_point_are_those_a_tree_over_every_face_finds():
    from scipy.spatial import cKDTree

    from icefarm.stages.surface.fringe import _cut_near

    mesh = trimesh.creation.icosphere(5, radius=0.1)
    v, f = mesh.vertices, mesh.faces
    h = v[f, 2]
    low, high = h.min(axis=1), h.max(axis=1)
    tree = cKDTree(v[f].mean(axis=1))
    for level, centre, reach in ((0.0, (0.1, 0, 0), 0.03), (0.05, (0, 0.08, 0.05), 0.05), (-0.099, (0, 0, -0.1), 0.02)):
        expected = np.asarray(tree.query_ball_point(centre, reach), dtype=np.int64)
        expected = expected[(low[expected] <= level) & (high[expected] >= level)]
        got = _cut_near(f, v, np.flatnonzero(low <= level), high, level, np.array(centre), reach)
        assert len(expected) and np.array_equal(np.sort(got), np.sort(expected))
