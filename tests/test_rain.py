"""Driving rain (icefarm.stages.rain): the wind slants the storm's rain onto the faces that
turn towards it; a level top gets the same, the lee none, still air is as before."""

import numpy as np
import pytest
import trimesh

from icefarm import params
from icefarm.spatial import ray_caster
from icefarm.stages.rain import FALL_SPEED, open_sky, rain_vector
from icefarm.stages.storm import StormOptions, precipitation_m, refine, storm_water

G = np.array([0.0, -1.0, 0.0])


def _plate(max_edge=0.03):
    """A sign's plate: 0.6 m wide (x), 0.6 m high (y), 2 cm thick (z), its foot 1.6 m up."""
    box = trimesh.creation.box([0.6, 0.6, 0.02])
    box.apply_translation([0.0, 1.9, 0.0])
    return refine(box, max_edge)


def _storm(mesh, **kw):
    p = params.typed("storm", {"wind": (0.0, 0.0, 0.0), **kw})  # still air unless a test blows
    return storm_water(mesh, G, StormOptions(p, 0.5, 75.0), cast=ray_caster(mesh)).storm


def _faces(mesh):
    """Vertex masks of the plate's top, windward (-z), lee (+z) and bottom faces, corners off."""
    v, n = mesh.vertices, mesh.vertex_normals
    inner = (np.abs(v[:, 0]) < 0.28) & (np.abs(v[:, 1] - 1.9) < 0.28)
    return {"top": n[:, 1] > 0.99, "windward": (n[:, 2] < -0.99) & inner, "lee": (n[:, 2] > 0.99) & inner,
            "bottom": n[:, 1] < -0.99}


def test_the_rain_slants_with_the_wind_across_gravity_only():
    assert np.array_equal(rain_vector(G, (0.0, 0.0, 0.0)), G)
    assert np.array_equal(rain_vector(G, (0.0, 7.0, 0.0)), G)  # an updraft is not a slant
    r = rain_vector(G, (3.0, 2.0, 4.0))
    assert r == pytest.approx([3.0 / FALL_SPEED, -1.0, 4.0 / FALL_SPEED])


def test_a_sign_in_still_air_catches_rain_on_its_top_edge_only():
    mesh = _plate()
    storm = _storm(mesh)
    faces = _faces(mesh)
    assert storm.catch[faces["top"]].sum() > 0
    assert storm.catch[faces["windward"] | faces["lee"] | faces["bottom"]].sum() == 0
    P = precipitation_m("moderate")
    assert storm.budget.caught < 0.1 * P * 0.6 * 0.6  # the edge's share, not the face's


def test_wind_wets_the_windward_face_by_its_speed_and_leaves_the_lee_dry():
    mesh = _plate()
    wind = 4.0
    calm, windy = _storm(mesh), _storm(mesh, wind=(0.0, 0.0, wind))  # blowing towards +z: -z faces it
    faces = _faces(mesh)
    area = np.bincount(mesh.faces.ravel(), weights=np.repeat(mesh.area_faces / 3, 3), minlength=len(mesh.vertices))
    P = precipitation_m("moderate")
    per_area = windy.catch[faces["windward"]] / area[faces["windward"]]
    assert np.median(per_area) == pytest.approx(P * wind / FALL_SPEED, rel=1e-6)
    assert windy.catch[faces["lee"]].sum() == 0
    # a level top gets the precipitation depth whatever the wind
    assert windy.catch[faces["top"]].sum() == pytest.approx(calm.catch[faces["top"]].sum(), rel=1e-9)
    b = windy.budget
    assert b.caught == pytest.approx(b.frozen + b.shed + b.pooled, rel=1e-9)
    # the windward face glazes, and what it cannot freeze drips from the plate's lower rim
    assert np.median(windy.ice[faces["windward"]]) > 0.001
    assert windy.shed.sum() > 10 * calm.shed.sum()


def test_a_roof_shelters_a_wall_from_still_rain_but_not_from_the_wind():
    roof = trimesh.creation.box([1.0, 0.05, 1.0])
    roof.apply_translation([0.0, 1.0, 0.0])
    wall = trimesh.creation.box([0.6, 0.6, 0.6])
    wall.apply_translation([0.0, 0.5, 0.0])
    mesh = refine(trimesh.util.concatenate([roof, wall]), 0.05)
    cast = ray_caster(mesh)
    n = mesh.vertex_normals
    facing_wind = (n[:, 2] < -0.99) & (np.abs(mesh.vertices[:, 0]) < 0.25) & (mesh.vertices[:, 1] < 0.6)
    assert not open_sky(mesh, G, cast)[facing_wind].any()
    # rain at 45 degrees passes under the 0.2 m eave onto the lower part of the wall
    assert open_sky(mesh, rain_vector(G, (0.0, 0.0, FALL_SPEED)), cast)[facing_wind].any()
