"""Stage 4 (paper 4.4): icicles, bases and glaze as one watertight mesh; tubes mode.

Stage 4's inputs are made by hand with conftest's ``surface_kit``.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from icefarm import metaballs as M, params
from icefarm.errors import InputError
from icefarm.metaballs import fuse
from icefarm.stages import surface as S
from icefarm.stages.trajectories import TrajectoryResult

G = np.array([0.0, -1.0, 0.0])
TIP = 0.00244


def _mesh(ice):
    return trimesh.Trimesh(ice.vertices, ice.faces, process=False)


def _closed_and_clean(ice):
    m = _mesh(ice)
    assert len(ice.faces) > 0
    assert ice.vertices.dtype == np.float64 and ice.faces.dtype == np.int64
    assert m.is_watertight and m.is_winding_consistent
    assert m.area_faces.min() > 1e-13  # no sliver: edges of a micrometre or more
    assert m.volume > 0  # outward normals
    return m


def _radius_along(ice, top, length, fractions):
    """Distance from axis points (hanging from ``top``) to the nearest ice vertex."""
    axis = top + np.outer(np.asarray(fractions) * length, G)
    d, _ = trimesh.proximity.ProximityQuery(_mesh(ice)).vertex(axis)
    return d


def test_profile_follows_equation_1():
    x = np.array([0.0, 0.02, 0.05, 0.08])
    r = S.profile_radius(x, 0.08, S.Profile(TIP, 0.012, 0.0, 628.3))
    assert np.allclose(r, TIP + (0.08 - x) * 0.012)
    rippled = S.profile_radius(x, 0.08, S.Profile(TIP, 0.012, 0.0002, 628.3))
    free = x < 0.08 - S.TIP_CALM * TIP  # the ripple fades out at the tip
    assert np.allclose(rippled[free], r[free] + 0.0002 * np.sin(x[free] * 628.3))
    assert rippled[-1] == pytest.approx(TIP)


def test_sphere_with_icicles_bases_and_glaze_is_one_watertight_mesh(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    wet = obj.vertices[:, 1] > 0.02
    starts = [[0.0, -0.15, 0.0], [0.05, -0.14, 0.0], [-0.04, -0.14, 0.03]]
    drips = kit.drips(obj, starts)
    traj = kit.straight(drips.positions, [0.06, 0.04, 0.05])
    surface, glaze = kit.groups()
    ice = kit.ice(obj, kit.water(obj, wet), drips, traj, surface, glaze)
    _closed_and_clean(ice)
    assert len(ice.icicles.taper) == 3
    # The glaze covers the wet cap: ice vertices lie above the top of the sphere.
    assert ice.vertices[:, 1].max() > 0.15
    # Icicles hang below the sphere down to about their tips.
    assert ice.vertices[:, 1].min() == pytest.approx(-0.15 - 0.06 - TIP, abs=0.002)


def test_single_icicle_tip_radius_within_ten_percent_at_default_voxel(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    traj = kit.straight(drips.positions, [0.08])
    surface, glaze = kit.groups(surface__base_balls=0)  # a base of 0.1 m of water would swell past 10 % of the trunk
    ice = kit.ice(obj, kit.dry(obj), drips, traj, surface, glaze)
    _closed_and_clean(ice)
    assert ice.icicles.tip_radius_mm == pytest.approx(2.44, rel=0.10)
    # Both profiles reach tip + t L at the base: (base - tip diameter) / L = 2 t.
    assert ice.icicles.growth_ratio[0] == pytest.approx(2 * surface.growth_ratio, rel=0.15)
    # about 3 cm of ripple between the quiet tip and the base: the wavelength wanders (25 %) there
    assert ice.icicles.ripple_wavelength_cm == pytest.approx(1.0, rel=0.3)


def test_without_ripples_the_radius_only_shrinks_towards_the_tip(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    top, length = drips.positions[0], 0.08
    traj = kit.straight(drips.positions, [length])
    fractions = np.linspace(0.25, 0.9, 40)
    smooth = kit.ice(obj, kit.dry(obj), drips, traj, *kit.groups(surface__ripple_amplitude=0.0, surface__noise=0.0))
    r = _radius_along(smooth, top, length, fractions)
    assert np.all(np.diff(r) <= 0.05 * 0.001)  # within a twentieth of a voxel
    assert np.isnan(smooth.icicles.ripple_wavelength_cm) and np.isnan(smooth.icicles.ripple_amplitude_mm)
    rippled = kit.ice(obj, kit.dry(obj), drips, traj, *kit.groups(surface__ripple_amplitude=0.0005, surface__noise=0.0))
    r = _radius_along(rippled, top, length, fractions)
    # twice the smooth one's tolerance: the ripples are quiet near the tip and fade around the trunk
    assert np.diff(r).max() > 0.0001


def test_larger_growth_ratio_gives_a_wider_base(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    traj = kit.straight(drips.positions, [0.08])
    ratios = [kit.ice(obj, kit.dry(obj), drips, traj, *kit.groups(surface__growth_ratio=t)).icicles.growth_ratio[0]
              for t in (0.02, 0.06)]
    assert ratios[1] > 2 * ratios[0]


def test_icicles_closer_than_their_radii_fuse_into_one_component(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    surface, glaze = kit.groups(surface__base_balls=0, surface__noise=0.0)
    for gap, components in ((0.003, 1), (0.03, 2)):
        drips = kit.drips(obj, [[-gap / 2, -0.15, 0.0], [gap / 2, -0.15, 0.0]])
        traj = kit.straight(drips.positions, [0.05, 0.05])
        ice = kit.ice(obj, kit.dry(obj), drips, traj, surface, glaze)
        assert len(_mesh(ice).split(only_watertight=False)) == components


@pytest.mark.slow
def test_glaze_lifetime_moves_the_thickness_between_top_and_bottom(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    water = kit.water(obj, np.ones(len(obj.vertices), bool))  # wet all over: dUp, dDown span 0.3 m
    drips = kit.drips(obj, np.zeros((0, 3)))
    thick = {}
    for lt in (0.0, 1.0):
        surface, glaze = kit.groups(glaze__lifetime=lt, glaze__min_radius=0.0005, glaze__scale=0.015,
                                    surface__voxel_size=0.002)
        ice = kit.ice(obj, water, drips, kit.no_icicles(), surface, glaze)
        _closed_and_clean(ice)
        out = np.linalg.norm(ice.vertices, axis=1) - 0.15
        y = ice.vertices[:, 1]
        thick[lt] = np.median(out[(out > 0) & (y > 0.1)]), np.median(out[(out > 0) & (y < -0.1)])
    # lt = 0: dDown rules, the ice is thick high up; lt = 1: dUp rules, thick low down.
    assert thick[0.0][0] > 1.5 * thick[0.0][1]
    assert thick[1.0][1] > 1.5 * thick[1.0][0]


def test_glaze_thickness_is_the_equation_3_radius(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    water = kit.water(obj, np.ones(len(obj.vertices), bool))
    surface, glaze = kit.groups(glaze__min_radius=0.002, glaze__scale=0.0,
                                surface__voxel_size=0.0015)
    ice = kit.ice(obj, water, kit.drips(obj, np.zeros((0, 3))), kit.no_icicles(), surface, glaze)
    out = np.linalg.norm(ice.vertices, axis=1) - 0.15
    assert np.median(out[out > 0]) == pytest.approx(0.002, rel=0.2)


@pytest.mark.slow
def test_glaze_on_its_coarser_lattice_cuts_the_faces_and_keeps_mesh_and_tips(monkeypatch, surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    water = kit.water(obj, obj.vertices[:, 1] < -0.1)  # a wet cap where the icicles hang
    starts = [[0.0, -0.15, 0.0], [0.03, -0.147, 0.0], [-0.02, -0.148, 0.02]]
    drips = kit.drips(obj, starts)
    traj = kit.straight(drips.positions, [0.06, 0.04, 0.05])
    small_bases = {"surface__base_scale": 0.03}  # 0.1 m of water would swell bases past the glaze's faces
    one_field = kit.ice(obj, water, drips, traj, *kit.groups(glaze__voxel_size=0.001, **small_bases))
    # The union runs only near the icicles: the boolean of the whole meshes is not needed.
    monkeypatch.setattr(fuse, "union_meshes", lambda parts: pytest.fail("fell back to the whole-mesh union"))
    surface, glaze = kit.groups(**small_bases)
    assert glaze.voxel_size > surface.voxel_size
    fused = kit.ice(obj, water, drips, traj, surface, glaze)
    m = _closed_and_clean(fused)
    assert len(fused.faces) < 0.4 * len(one_field.faces)
    assert fused.balls == one_field.balls
    assert fused.icicles.tip_radius_mm == pytest.approx(2.44, rel=0.10)
    assert np.allclose(fused.icicles.growth_ratio, one_field.icicles.growth_ratio, rtol=0.2)
    assert np.allclose(fused.icicles.taper, one_field.icicles.taper, rtol=0.2)
    # Icicles, glaze and the bases under them are one solid: each icicle hangs from the coat.
    assert len(m.split(only_watertight=False)) <= 3
    assert fused.vertices[:, 1].min() == pytest.approx(one_field.vertices[:, 1].min(), abs=0.0005)
    # The coat still lies outside the object, around Equation 3's thickness.
    from icefarm.stages.surface.glaze import glaze_thickness

    wet = water.supply & (obj.vertices[:, 1] < -0.12)  # clear of the thinning edge of the wet cap
    eq3 = glaze_thickness(water, glaze)[wet]
    out = np.linalg.norm(fused.vertices, axis=1) - 0.15
    far = (np.hypot(fused.vertices[:, 0], fused.vertices[:, 2]) > 0.06) & (out > 0) & (fused.vertices[:, 1] < -0.12)
    assert 0.5 * np.median(eq3) < np.median(out[far]) < eq3.max() + 0.0005


def test_fusing_two_lattices_is_the_union_of_the_solids():
    # One Gaussian ball weighing LEVEL * e is a sphere of radius = its width.
    def ball(centre, radius, voxel):
        b = M.Balls(np.array([centre], float), np.array([radius]), np.array([M.LEVEL * np.e]))
        return M.sample_field(b, voxel)

    r, d = 0.01, 0.012
    fine = 0.0006  # against 0.001: lattices whose points do not line up (0.0004 works too, more slowly)
    verts, faces = M.fuse_fields(ball([0.0, 0.0, 0.0], r, fine), ball([d, 0.0, 0.0], r, 0.001))
    m = trimesh.Trimesh(verts, faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.area_faces.min() > 0
    lens = np.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    assert m.volume == pytest.approx(2 * 4 / 3 * np.pi * r**3 - lens, rel=0.03)
    assert len(m.split(only_watertight=False)) == 1
    # Apart, the two spheres stay two; one deep inside the other vanishes.
    m = trimesh.Trimesh(*M.fuse_fields(ball([0, 0, 0], r, fine), ball([0.05, 0, 0], r, 0.001)), process=False)
    assert m.is_watertight and len(m.split(only_watertight=False)) == 2
    assert m.volume == pytest.approx(2 * 4 / 3 * np.pi * r**3, rel=0.03)
    m = trimesh.Trimesh(*M.fuse_fields(ball([0, 0, 0], 0.003, fine), ball([0, 0, 0], 0.03, 0.001)), process=False)
    assert m.is_watertight and len(m.split(only_watertight=False)) == 1
    assert m.volume == pytest.approx(4 / 3 * np.pi * 0.03**3, rel=0.03)
    # The whole-mesh union (the fallback) agrees.
    a, b = trimesh.creation.icosphere(4, r), trimesh.creation.icosphere(4, r)
    b.apply_translation([d, 0, 0])
    m = trimesh.Trimesh(*M.union_meshes([(a.vertices, a.faces), (b.vertices, b.faces)]), process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(2 * 4 / 3 * np.pi * r**3 - lens, rel=0.03)
    # An empty side gives the other.
    v, f = M.fuse_fields(None, ball([0, 0, 0], r, 0.001))
    assert trimesh.Trimesh(v, f).is_watertight
    assert M.fuse_fields(None, None)[1].shape == (0, 3)


def test_coarse_glaze_apart_from_icicles_or_alone_stays_closed(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    top = obj.vertices[:, 1] > 0.1  # glaze on the top, icicles at the bottom: nothing to unite
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    traj = kit.straight(drips.positions, [0.04])
    surface, glaze = kit.groups()
    ice = kit.ice(obj, kit.water(obj, top), drips, traj, surface, glaze)
    m = _closed_and_clean(ice)
    assert len(m.split(only_watertight=False)) >= 2
    assert ice.icicles.tip_radius_mm == pytest.approx(2.44, rel=0.10)
    coat = kit.ice(obj, kit.water(obj, top), kit.drips(obj, np.zeros((0, 3))), kit.no_icicles(), surface, glaze)
    _closed_and_clean(coat)
    assert np.isnan(coat.icicles.tip_radius_mm)


def test_a_glaze_voxel_too_fine_is_refused_by_name(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    water = kit.water(obj, np.ones(len(obj.vertices), bool))
    surface, glaze = kit.groups(surface__voxel_size=0.00001, glaze__voxel_size=0.00002)
    with pytest.raises(InputError, match="glaze.voxel_size"):
        kit.ice(obj, water, kit.drips(obj, np.zeros((0, 3))), kit.no_icicles(), surface, glaze)


def test_tubes_mode_gives_one_closed_tube_per_branch(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0], [0.05, -0.14, 0.0]])
    pts = drips.positions[0] + np.linspace(0, 0.06, 16)[:, None] * G
    bend = np.array([1.0, -1.0, 0.3]) / np.linalg.norm([1.0, -1.0, 0.3])
    branch = pts[5] + np.linspace(0, 0.03, 8)[:, None] * bend
    other = drips.positions[1] + np.linspace(0, 0.04, 11)[:, None] * G
    traj = TrajectoryResult(np.concatenate([pts, branch, other]), np.array([0, 16, 24, 35]),
                            np.array([0, 0, 1]), np.array([-1, 0, -1]))
    ice = kit.ice(obj, kit.water(obj, obj.vertices[:, 1] > 0), drips, traj, *kit.groups(surface__mode="tubes"))
    assert ice.balls == 0
    parts = _mesh(ice).split(only_watertight=False)
    assert len(parts) == traj.n_branches
    for part in parts:
        assert part.is_watertight and part.is_winding_consistent and part.volume > 0
    assert ice.icicles.tip_radius_mm == pytest.approx(2.44, rel=0.1)


def test_nothing_to_build_gives_an_empty_mesh(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    surface, glaze = kit.groups(glaze__mode="none")
    ice = kit.ice(obj, kit.dry(obj), kit.drips(obj, np.zeros((0, 3))), kit.no_icicles(), surface, glaze)
    assert ice.vertices.shape == (0, 3) and ice.faces.shape == (0, 3)
    assert np.isnan(ice.icicles.tip_radius_mm) and len(ice.icicles.taper) == 0


def test_a_voxel_too_fine_for_the_ice_is_refused_with_advice(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    drips = kit.drips(obj, [[0.0, -0.15, 0.0]])
    surface, glaze = kit.groups(surface__voxel_size=0.00002)
    with pytest.raises(InputError, match="voxel_size"):
        kit.ice(obj, kit.dry(obj), drips, kit.straight(drips.positions, [0.1]), surface, glaze)


def test_inconsistent_inputs_are_refused(surface_kit):
    kit = surface_kit
    obj = kit.sphere()
    water = kit.dry(trimesh.creation.box())
    with pytest.raises(ValueError, match="water"):
        kit.ice(obj, water, kit.drips(obj, np.zeros((0, 3))), kit.no_icicles(), *kit.groups())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cow.obj", "teapot.obj"])
def test_real_meshes_through_stages_1_to_4_are_watertight(name, shared_mesh):
    path = shared_mesh(name)
    from icefarm.job import run_stages
    from icefarm.mesh import prepare

    p = params.resolve({"storm.mode": "relative", "drips.count": 8, "water.rays": 800, "surface.voxel_size": 0.0015})
    result = run_stages(prepare(path, 0.3), p, 1)
    inputs = S.IceInputs(result.mesh, result.flow, result.water, result.drips, result.trajectories)
    ice = S.build_ice(inputs, p.surface, p.glaze, G, np.random.default_rng(1))
    _closed_and_clean(ice)
    assert np.isfinite(ice.icicles.tip_radius_mm)


def test_a_cut_icicle_thickens_as_if_longer_and_rests_on_its_foot(surface_kit):
    """An icicle the ground stopped keeps its water: its profile follows a longer icicle
    (at most GROUND_THICKENING times its own length), so it tapers more than a free one of
    the same length, and its foot stands on the ground, not in it."""
    from icefarm.placement import stop_at_ground
    from icefarm.stages.surface.profile import GROUND_THICKENING, grown_lengths

    kit = surface_kit
    grown = grown_lengths(np.array([0.1, 0.1]), np.array([0.0, 1.0]))
    assert grown == pytest.approx([0.1, 0.1 * (1 + GROUND_THICKENING)])
    obj = trimesh.creation.box([0.2, 0.01, 0.2])
    start = [0.0, -0.005, 0.0]
    floor = -0.005 - 0.08 - 0.00244
    free, long = kit.straight([start], [0.08]), kit.straight([start], [0.16])
    cut = stop_at_ground(long, G, floor=floor, margin=0.00244)
    assert cut.cut[0] == pytest.approx(0.08) and cut.branch(0)[-1] == pytest.approx(free.branch(0)[-1])
    p = params.resolve({"surface.impurity": 0.0, "surface.base_balls": 0, "glaze.mode": "none"})
    free_ice = S.build_ice(S.IceInputs(obj, obj, kit.dry(obj), kit.drips(obj, [start]), free), p.surface, p.glaze,
                           G, np.random.default_rng(0))
    cut_ice = S.build_ice(S.IceInputs(obj, obj, kit.dry(obj), kit.drips(obj, [start]), cut), p.surface, p.glaze,
                          G, np.random.default_rng(0))
    assert cut_ice.icicles.taper[0] > 1.2 * free_ice.icicles.taper[0]
    assert cut_ice.vertices[:, 1].min() >= floor - 1e-6  # on the ground, not in it
    assert np.isnan(cut_ice.icicles.tip_radius_mm)  # a foot, not a drop: no tip to measure


def test_bases_are_never_thicker_than_the_rim_they_hang_from(surface_kit):
    """On an eave's 1 cm slab a base is a fillet, not a glass knob past both faces."""
    kit = surface_kit
    from icefarm.metaballs.balls import LEVEL
    from icefarm.stages.surface.bases import BASE_SINK, BASE_THICKNESS, base_balls, object_thickness

    slab = trimesh.creation.box(extents=(0.4, 0.01, 0.3))  # 1 cm thick, faces at y = +-0.005
    rim = [[x, -0.005, 0.149] for x in np.linspace(-0.15, 0.15, 7)]  # on the underside, at the edge
    drips = kit.drips(slab, rim, water=0.3)  # much water: bases that would swell to 15 mm and more
    surface, _ = kit.groups(surface__base_scale=0.3)
    balls = base_balls(slab, drips, surface, np.random.default_rng(0), np.full(len(rim), 0.03),
                       gravity=np.array([0.0, -1.0, 0.0]))
    assert len(balls) > 0
    radius = balls.widths  # BASE_KAPPA 1: a lone ball's surface sits at its width
    assert radius.max() <= BASE_THICKNESS * 0.01 + 1e-9
    # a ball on a big face reaches at most 0.9 of the way through and stands at most 0.3 of it proud
    flat = balls.centers[:, 2] < 0.14  # on the underside, clear of the end face
    assert flat.any()
    depth = np.abs(np.abs(balls.centers[flat, 1]) - 0.005)  # how far inside its face each centre sits
    assert np.allclose(depth, BASE_SINK * radius[flat], atol=1e-6)
    assert (depth + radius[flat] <= 0.01 + 1e-9).all() and (radius[flat] - depth <= 0.3 * 0.01 + 1e-9).all()
    # the ray cast against the normal reads the slab's thickness
    t = object_thickness(slab, np.array([[0.0, 0.005, 0.0], [0.0, -0.005, 0.1]]), np.array([[0, 1.0, 0], [0, -1.0, 0]]))
    assert np.allclose(t, 0.01, atol=1e-6)
    assert np.all(balls.weights == balls.weights[0]) and balls.weights[0] > LEVEL
