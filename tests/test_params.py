"""The parameter boundary: `resolve` validates once into a frozen, typed `Params`."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from icefarm import params
from icefarm.errors import InputError
from icefarm.job.cache import digest


def test_resolve_types_every_group_and_normalises_gravity_once():
    p = params.resolve({"water.gravity": [0, 0, -4], "surface.noise": 0.001}, {"drips.count": 7})
    assert isinstance(p, params.Params) and isinstance(p.surface, params.SurfaceParams)
    assert p.surface.noise == 0.001 and p.drips.count == 7 and isinstance(p.drips.count, int)
    assert p.water.gravity == (0.0, 0.0, -1.0) and np.allclose(p.gravity, [0, 0, -1])
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.surface.noise = 0.0  # type: ignore[misc]


def test_as_dict_round_trips_and_hashes_like_the_params_it_holds():
    p = params.resolve({"trajectories.wind": "1 0 0", "glaze.mode": "none"})
    plain = p.as_dict()
    assert set(plain) == set(params.GROUPS) and plain["trajectories"]["wind"] == [1.0, 0.0, 0.0]
    assert params.resolve(plain) == p and pickle.loads(pickle.dumps(p)) == p
    assert digest(p) == digest(plain) and digest(p.surface) == digest(plain["surface"])


def test_updated_lays_values_over_and_validates_them_again():
    p = params.resolve({"surface.noise": 0.001})
    q = p.updated({"growth.frames": 4})
    assert q.growth.frames == 4 and q.surface.noise == 0.001 and p.growth.frames != 4
    with pytest.raises(InputError, match="growth.frames"):
        p.updated({"growth.frames": -1})
    with pytest.raises(InputError, match="did you mean surface.noise"):
        params.resolve({"surface.nosie": 0.1})


def test_the_written_out_groups_hold_the_registry_fields_in_order_with_their_types():
    """Adding a parameter to the registry without its field in `icefarm.param_groups`, or a
    field without its parameter, fails here."""
    assert tuple(params.GROUPS) == tuple(params._GROUP_TYPES)
    for group in params.GROUPS:
        cls = params.group_type(group)
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen, group
        assert getattr(params, cls.__name__) is cls, group
        expected = [(p.name, params._PYTHON_TYPES[p.kind]) for p in params.PARAMS
                    if p.group == group and p.key not in params._RETIRED]
        assert [(f.name, f.type) for f in dataclasses.fields(cls)] == expected, group
    with pytest.raises(ValueError, match="no parameter group"):
        params.group_type("glazes")


# Values the stages no longer check themselves: the registry refuses them, once, in `resolve`.
@pytest.mark.parametrize("key, value", [
    ("water.rays", 0), ("water.influence_radius", 0.0), ("water.pools", "flood"),
    ("drips.drip_limit", 90.0), ("drips.spacing", -0.01), ("drips.distribution", "uniform"),
    ("drips.min_fall", -0.01), ("trajectories.division_probability", 1.5), ("trajectories.step_length", 0.0),
    ("trajectories.length_scale", 0.0), ("trajectories.max_branches", 0), ("trajectories.max_tilt", 91.0),
    ("trajectories.branch_spread", -0.01), ("ground_ice.runoff", 1.5), ("ground_ice.merge", -0.01),
    ("storm.intensity", "extreme"), ("proxy.mode", "sometimes"), ("surface.profile", "cone"),
])
def test_the_registry_refuses_what_the_stages_do_not_check(key, value):
    with pytest.raises(InputError, match=f"{key} = .* out of its domain"):
        params.resolve({key: value})
