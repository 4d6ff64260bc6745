"""The icicle's look: physical profile, taper, growth ratio and ripples tied to impurity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from icefarm.stages.surface import Profile, profile_radius
from icefarm.stages.surface.profile import PHYSICAL_EXPONENT, profile_args

TIP = 0.00244  # the default tip radius (m)


@pytest.fixture
def one_icicle(surface_kit):
    """``one_icicle(length=0.12, **changes)``: the measures of one straight icicle under a dry sphere."""
    kit = surface_kit

    def grow(length=0.12, **changes):
        obj = kit.sphere()
        drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
        traj = kit.straight(drips.positions, [length])
        return kit.ice(obj, kit.dry(obj), drips, traj, *kit.groups(**changes)).icicles

    return grow


def test_physical_profile_is_tip_plus_k_d_to_the_three_quarters():
    length, t = 0.1, 0.05
    x = np.linspace(0.0, length, 11)
    r = profile_radius(x, length, Profile(TIP, t, 0.0, 628.3, shape="physical"))
    d = length - x
    assert np.allclose(r, TIP + t * length**0.25 * d**PHYSICAL_EXPONENT)
    # Both shapes reach tip + t L at the base and the tip radius at the tip.
    paper = profile_radius(x, length, Profile(TIP, t, 0.0, 628.3, shape="paper"))
    assert r[0] == pytest.approx(paper[0]) and r[-1] == pytest.approx(TIP) == paper[-1]
    # A carrot, not a cone: fuller than the cone everywhere between.
    assert np.all(r[1:-1] > paper[1:-1])


def test_impurity_scales_the_ripple_amplitude(surface_kit):
    _, surface = None, surface_kit.groups(surface__impurity=0.5, surface__ripple_amplitude=0.001)[0]
    assert profile_args(surface).amplitude == pytest.approx(0.0005)
    assert profile_args(surface_kit.groups(surface__impurity=0.0)[0]).amplitude == 0.0


def test_physical_profile_measures_three_quarters_and_paper_a_cone(one_icicle):
    smooth = {"surface__impurity": 0.0, "surface__noise": 0.0}
    physical = one_icicle(**smooth)
    paper = one_icicle(surface__profile="paper", **smooth)
    assert 0.6 <= physical.profile_exponent[0] <= 0.9
    assert 0.9 <= paper.profile_exponent[0] <= 1.2


def test_defaults_taper_like_a_carrot_with_a_real_growth_ratio(one_icicle):
    m = one_icicle()
    assert m.taper[0] >= 3.0
    assert 1 / 32 <= m.growth_ratio[0] <= 1 / 6
    assert m.tip_radius_mm == pytest.approx(2.44, rel=0.1)


def test_a_bud_has_no_taper_to_measure(one_icicle):
    # 2 cm: long enough for radius samples (its growth ratio is measured), too short for a
    # carrot at the real growth ratio
    m = one_icicle(length=0.02)
    assert np.isnan(m.taper[0]) and np.isfinite(m.growth_ratio[0])


def test_ripples_show_at_the_defaults_and_track_the_amplitude(one_icicle):
    default = one_icicle()
    assert default.ripple_amplitude_mm >= 0.4
    assert default.ripple_wavelength_cm == pytest.approx(1.0, rel=0.15)
    # ripple_amplitude is a whole crest's depth; crests fade and tilt around the trunk, so the
    # radius measured around it keeps a steady share of it (about 0.4), whatever the depth
    shares = []
    for amplitude in (0.0006, 0.0012, 0.0018):
        m = one_icicle(surface__impurity=1.0, surface__ripple_amplitude=amplitude)
        shares.append(m.ripple_amplitude_mm / (amplitude * 1000))
    assert min(shares) >= 0.3 and max(shares) <= 1.0
    assert max(shares) / min(shares) < 1.25


def test_pure_water_grows_smooth_icicles_measured_as_no_ripple(one_icicle):
    m = one_icicle(surface__impurity=0.0)
    assert np.isnan(m.ripple_amplitude_mm) and np.isnan(m.ripple_wavelength_cm)


@pytest.mark.parametrize("frequency", [314.0, 628.3, 1200.0])
def test_ripple_frequency_sets_the_wavelength(frequency, one_icicle):
    m = one_icicle(surface__ripple_frequency=frequency, surface__impurity=1.0)
    assert m.ripple_wavelength_cm == pytest.approx(2 * np.pi / frequency * 100, rel=0.15)


@pytest.fixture
def base_volume(surface_kit):
    """``base_volume(**changes)``: ice volume (cm^3) that the bases add to two icicles of 6 cm of water on a sphere."""
    import trimesh

    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0], [0.05, -0.14, 0.0]], water=0.06)
    traj = kit.straight(drips.positions, [0.12, 0.08])

    def volume(**c):
        ice = kit.ice(obj, kit.dry(obj), drips, traj, *kit.groups(**c))
        return trimesh.Trimesh(ice.vertices, ice.faces).volume * 1e6

    return lambda **changes: volume(**changes) - volume(**{**changes, "surface__base_balls": 0})


def test_bases_show_at_the_defaults(base_volume):
    # At least a tenth of the two icicles' volume (about 30 cm^3) swells their bases.
    assert base_volume() > 3.0


def test_base_balls_and_extent_each_add_ice_monotonically(base_volume):
    # three times the default voxel: twelve quick meshings, each step still +0.2 cm^3 or more
    coarse = {"surface__voxel_size": 0.003}
    by_count = [base_volume(surface__base_balls=n, **coarse) for n in (10, 20, 40)]
    by_extent = [base_volume(surface__base_extent=eb, **coarse) for eb in (0.01, 0.02, 0.03)]
    assert np.all(np.diff(by_count) > 0) and np.all(np.diff(by_extent) > 0)


@pytest.mark.slow
def test_the_bunny_at_the_defaults_grows_carrots_not_straws(shared_mesh, tmp_path):
    """The taper on a real job: the 0.3 m bunny, every default, grounded. Half its drip rims
    sit a few cm over the ground; without room to hang (drips.min_fall) and the thickening of
    cut icicles its median taper is 2.5. The relative storm (the paper's knobs):
    under the physical storm's defaults the 0.3 m bunny's catchments grow 3-4 cm icicles,
    whose taper stays near 2 with one growth ratio for all."""
    import json

    from icefarm import params
    from icefarm.job.pipeline import JobSpec, Stage, run_job

    spec = JobSpec("bunny", str(shared_mesh("stanford-bunny.obj")), 0.3, params.resolve({"storm.mode": "relative"}),
                   seed=0)
    outcome = run_job(spec, tmp_path / "job", until=Stage.SURFACE)
    assert outcome.status == "done", outcome.error
    t = json.loads((tmp_path / "job" / "timings.json").read_text())
    taper = [v for v in t["taper"] if v is not None]
    assert len(taper) >= 10 and np.median(taper) >= 3.0
    assert 0.6 <= np.median([v for v in t["profile_exponent"] if v is not None]) <= 0.9
    assert t["ripple_amplitude_mm"] >= 0.4 and t["upward_share"] == 0.0
    # The ripple texture on its trunks of 10 cm and more (none grow under the
    # physical storm's defaults): deep, decorrelated 3 cm along, unevenly spaced crests
    assert t["ripple_trunks"] >= 1 and t["ripple_depth_mm"] >= 0.4
    assert t["ripple_correlation_3cm"] <= 0.6 and 0.1 <= t["ripple_crest_cv"] <= 0.35


@pytest.mark.slow
def test_the_fountains_long_icicles_ripple_like_real_ones(tmp_path):
    """The ripple measures on the 0.4 m fountain overflowing, at the defaults (the physical
    storm): its upper bowl spills over its lip and grows icicles of 10 cm and more below it."""
    import json

    from icefarm import params
    from icefarm.job.pipeline import JobSpec, Stage, run_job

    spec = JobSpec("fountain", "generator:fountain", 0.4,
                   params.resolve({"water.pools": "overflow"}), seed=0)
    outcome = run_job(spec, tmp_path / "job", until=Stage.SURFACE)
    assert outcome.status == "done", outcome.error
    t = json.loads((tmp_path / "job" / "timings.json").read_text())
    assert t["water_pooled"] < 0.001  # both basins full: what they catch runs over their lips
    # a ragged fringe: a few long icicles among short ones (8 of 10 cm and more here)
    assert t["ripple_trunks"] >= 6 and t["ripple_depth_mm"] >= 0.4 and t["ripple_amplitude_mm"] >= 0.4
    assert t["ripple_correlation_3cm"] <= 0.6 and 0.1 <= t["ripple_crest_cv"] <= 0.35


def test_ripples_wander_and_break_like_real_ones_not_stacked_rings(monkeypatch, one_icicle):
    """The ripple measures on one 20 cm icicle at the defaults: deep enough, decorrelated 3 cm
    along, crest spacing varying by 10-35 %; the same carve with the texture off (one
    wavelength, crests level and whole) reads as identical rings and fails them."""
    natural = one_icicle(length=0.2).ripple_texture
    assert natural.trunks == 1
    assert natural.depth_mm >= 0.4
    assert natural.correlation_3cm <= 0.6
    assert 0.1 <= natural.crest_cv <= 0.35
    from icefarm.stages.surface import ripples

    for name, value in (("WANDER", 0.0), ("TILT", 0.0), ("FADE_FLOOR", 1.0), ("FORK_SPACING", 1e9),
                        ("PATCH_FLOOR", 1.0), ("PATCH_GAIN", 1.0)):
        monkeypatch.setattr(ripples, name, value)
    rings = one_icicle(length=0.2).ripple_texture
    assert rings.correlation_3cm > 0.8 and rings.crest_cv < 0.1


def test_ripples_run_deep_in_patches_with_calm_stretches_and_partial_rings():
    """Real ripples are deep on some stretches and sides of a trunk and nearly gone on
    others: along each of eight 30 cm branches a third or so is calm (under 0.6 of the full
    depth) and a third deep, a crest is deeper on one side than the other, and the mean
    square stays about that of the ripple without patches (the measured depth holds)."""
    from icefarm.stages.surface.ripples import PATCH_FLOOR, PATCH_GAIN, _patches, _texture

    branches = np.arange(8)
    texture = _texture(branches, 628.3, branches)
    x, angle = np.meshgrid(np.linspace(0.0, 0.3, 601), np.linspace(0, 2 * np.pi, 16, endpoint=False), indexing="ij")
    for b in branches:
        depth = _patches(texture, np.full(x.size, b), x.ravel(), np.cos(angle).ravel(),
                         np.sin(angle).ravel()).reshape(x.shape)
        assert depth.min() >= PATCH_FLOOR * PATCH_GAIN - 1e-12 and depth.max() <= PATCH_GAIN + 1e-12
        side = depth[:, 0]
        assert (side < 0.6 * PATCH_GAIN).mean() >= 0.25 and (side > 0.85 * PATCH_GAIN).mean() >= 0.25
        assert np.median(depth.max(axis=1) / depth.min(axis=1)) >= 1.4
        assert 0.85 <= np.mean(depth**2) <= 1.3


def test_a_crest_forks_on_an_arc_of_the_trunk_and_leaves_the_rest_whole():
    """Real ripple crests split and merge: each fork adds one crest on an arc of the trunk
    (the crests counted up the trunk through it), none off the arc, and changes nothing
    beyond its reach along the axis."""
    import dataclasses

    from icefarm.stages.surface.ripples import FORK_ARC, FORK_REACH, _fork_shift, _forks

    wavelength, radius = 0.0116, 0.006
    forks = _forks(np.array([3]), np.array([0.3]), wavelength)
    assert len(forks.x) >= 4 and np.all(np.diff(forks.x) >= FORK_REACH * wavelength)
    reach = FORK_REACH * wavelength
    k = 2 * np.pi / wavelength
    for f in range(len(forks.x)):
        one = dataclasses.replace(forks, offsets=np.array([0, 1]), x=forks.x[f:f + 1], key=forks.x[f:f + 1],
                                  stride=1.0, cos=forks.cos[f:f + 1], sin=forks.sin[f:f + 1], edge=forks.edge[f:f + 1])
        assert FORK_ARC[0] <= np.arccos(one.edge[0]) <= FORK_ARC[1]
        x = one.x[0] + np.linspace(-3 * reach, 3 * reach, 6001)
        centre = np.arctan2(one.sin[0], one.cos[0])
        crests = {}
        for where, angle in (("on", centre), ("off", centre + np.pi)):
            shift, core = _fork_shift(one, np.zeros(len(x), dtype=np.int64), x, radius * np.cos(angle) + 0 * x,
                                      radius * np.sin(angle) + 0 * x)
            wave = np.sin(k * x + shift)
            crests[where] = int(np.sum((wave[1:-1] > wave[:-2]) & (wave[1:-1] >= wave[2:]) & (wave[1:-1] > 0.5)))
            far = np.abs(x - one.x[0]) >= reach
            assert np.allclose(np.cos(shift[far]), 1.0) and np.all(core[far] == 1.0)
        assert crests["on"] == crests["off"] + 1


def test_pure_water_icicles_have_no_ripple_texture_and_tips_are_quiet(one_icicle):
    smooth = one_icicle(length=0.2, surface__impurity=0.0).ripple_texture
    assert smooth.depth_mm < 0.15  # the mesh's own bumps only
    from icefarm.stages.surface.ripples import TIP_QUIET, _envelope

    x = np.linspace(0.0, 0.2, 201)
    env = _envelope(x, 0.2, TIP)
    assert np.all(env[x > 0.2 - TIP_QUIET] == 0.0) and env[x < 0.15].min() == 1.0
    assert np.all(np.diff(env[x > 0.1]) <= 0)  # dies away towards the tip, never comes back


def test_ripples_rise_from_a_smooth_root_and_differ_from_icicle_to_icicle(surface_kit):
    """The amplitude fades into the base, and neighbours on one eave are not all
    ribbed alike (identical rings on every icicle read as a stack of glass coins)."""
    from icefarm.geometry import arc_lengths
    from icefarm.stages.surface.profile import grown_lengths, smooth_radius
    from icefarm.stages.surface.ripples import carve_ripples

    surface, _ = surface_kit.groups()
    prof = profile_args(surface)
    starts = np.stack([np.arange(8) * 0.05, np.zeros(8), np.zeros(8)], axis=1)
    traj = surface_kit.straight(starts, [0.2] * 8, step=0.002)
    x, lengths = arc_lengths(traj.points, traj.branch_offsets)
    branch = np.repeat(np.arange(8), np.diff(traj.branch_offsets))
    radius = smooth_radius(x, grown_lengths(lengths, traj.cut)[branch],
                           dataclasses.replace(prof, growth=traj.growth(prof.growth)[branch]))
    angle = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    ring = np.stack([np.cos(angle), np.zeros_like(angle), np.sin(angle)], axis=1)
    vertices = (traj.points[:, None, :] + radius[:, None, None] * ring[None]).reshape(-1, 3)
    moved = np.linalg.norm(carve_ripples(vertices, traj, prof) - vertices, axis=1).reshape(len(x), -1).mean(axis=1)
    frac = x / 0.2
    root = np.array([moved[(branch == b) & (frac < 0.05)].mean() for b in range(8)])
    middle = np.array([moved[(branch == b) & (frac > 0.4) & (frac < 0.6)].mean() for b in range(8)])
    assert np.all(root < 0.1 * middle)
    assert middle.max() / middle.min() > 1.4
    assert np.median(middle) * 1000 > 0.2  # a crest's mean displacement: 2/pi of its depth


def test_ripples_carved_in_chunks_on_every_core_equal_one_pass(surface_kit, monkeypatch):
    from icefarm.stages.surface import ripples

    surface, _ = surface_kit.groups()
    prof = profile_args(surface)
    traj = surface_kit.straight(np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.1, 0.0, 0.0]]), [0.2] * 3,
                                step=0.002)
    rng = np.random.default_rng(0)
    vertices = traj.points[rng.integers(0, len(traj.points), 3000)] + rng.normal(0.0, 0.004, (3000, 3))
    one_pass = ripples.carve_ripples_and_bands(vertices, traj, prof)
    monkeypatch.setattr(ripples, "_CHUNK", 10)
    monkeypatch.setattr(ripples.os, "cpu_count", lambda: 3)
    chunked = ripples.carve_ripples_and_bands(vertices, traj, prof)
    assert not np.array_equal(one_pass[0], vertices)
    assert np.array_equal(one_pass[0], chunked[0]) and np.array_equal(one_pass[1], chunked[1])


def test_ripple_texture_reads_the_surface_between_coarse_rings_of_vertices():
    """A tube rippled 0.7 mm every 1 cm, meshed in rings of vertices 2 mm apart (a 2 mm
    lattice's spacing: the eaves scene's). Half the 0.6 mm slabs hold no vertex; the radius
    read there from the nearest vertex alone came out short every other millimetre, and
    half the crests 2 mm apart (crest CV 0.6 on the eaves), and the ripple's band drowned in
    that noise. The section of the mesh's edges reads the even ripple as even."""
    from icefarm import params
    from icefarm.stages.surface.measure import measure_icicles, ripple_texture
    from icefarm.stages.trajectories import TrajectoryResult

    length, depth, wavelength = 0.2, 0.0007, 0.01
    s = np.arange(0.0002, length, 0.002)  # ring positions along the axis, off the 1 mm samples
    angle = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    radius = 0.01 + depth * np.sin(2 * np.pi * s / wavelength)
    vertices = np.stack([radius[:, None] * np.cos(angle), -np.broadcast_to(s[:, None], (len(s), len(angle))),
                         radius[:, None] * np.sin(angle)], axis=2).reshape(-1, 3)
    ring, step = np.meshgrid(np.arange(len(s) - 1), np.arange(len(angle)), indexing="ij")
    a = ring * len(angle) + step
    b = ring * len(angle) + (step + 1) % len(angle)
    faces = np.concatenate([np.stack([a, b, a + len(angle)], -1), np.stack([b, b + len(angle), a + len(angle)], -1)]
                           ).reshape(-1, 3)
    axis = np.stack([np.zeros(101), -np.linspace(0.0, length, 101), np.zeros(101)], axis=1)
    traj = TrajectoryResult(axis, np.array([0, 101]), np.array([0]), np.array([-1]))
    texture = ripple_texture(vertices, faces, traj)

    stats = measure_icicles(vertices, faces, traj, params.resolve({}).surface)
    assert texture.trunks == 1
    assert 0.5 < texture.depth_mm < 0.75  # the rings' chords between crests keep about 0.87 of it
    assert texture.crest_cv < 0.1 and texture.correlation_3cm > 0.8  # vertices alone: crest CV 0.57
    # The ripple's band stands out of the noise (vertices alone: "none", under the noise).
    assert 0.5 < stats.ripple_amplitude_mm < 0.75 and abs(stats.ripple_wavelength_cm - 1.0) < 0.1
