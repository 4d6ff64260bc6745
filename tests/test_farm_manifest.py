"""Manifest validation, sweep expansion and command-line --set (no jobs run here)."""

from pathlib import Path

import pytest
import yaml

from icefarm.errors import InputError
from icefarm.farm.manifest import Distribution, SweepMethod, load_manifest
from icefarm.farm.points import apply_sets, expand, parse_set, split_values, swept_keys

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def write(tmp_path: Path, data: dict, name: str = "m.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def manifest(ball: Path, **extra) -> dict:
    data = {"name": "t", "seed": 3, "render": None,
            "objects": [{"id": "ball", "mesh": ball.name, "size_m": 0.3}]}
    data.update(extra)
    return data


def problems(tmp_path: Path, data: dict) -> str:
    with pytest.raises(InputError) as info:
        load_manifest(write(tmp_path, data))
    return str(info.value)


def test_valid_manifest_resolves_paths_and_params(tmp_path, ball):
    data = manifest(ball, defaults={"surface": {"mode": "tubes"}, "drips.count": 5})
    data["objects"][0].update(params={"trajectories": {"curve_angle": 4}},
                              exclude=[{"min": [0, 0, 0], "max": [0.1, 0.1, 0.1]}, [[-1, -1, -1], [0, 0, 0]]],
                              material={"color": [0.9, 0.9, 1.0], "roughness": 0.1})
    m = load_manifest(write(tmp_path, data))
    obj = m.objects[0]
    assert Path(obj.mesh) == ball.resolve()
    assert m.defaults == {"surface.mode": "tubes", "drips.count": 5}
    assert obj.params == {"trajectories.curve_angle": 4.0}
    assert obj.exclude == (((0.0, 0.0, 0.0), (0.1, 0.1, 0.1)), ((-1.0, -1.0, -1.0), (0.0, 0.0, 0.0)))
    assert obj.material.color == (0.9, 0.9, 1.0) and obj.material.roughness == 0.1 and obj.material.type == "diffuse"
    assert m.render is None and m.sweep is None and m.seed == 3


def test_unknown_keys_get_a_nearest_match_hint(tmp_path, ball):
    data = manifest(ball, sweeep={"method": "grid"})
    data["objects"][0]["size"] = 0.3
    data["objects"][0]["params"] = {"trajectories.curve_angel": 3}
    text = problems(tmp_path, data)
    assert str(tmp_path / "m.yaml") in text
    assert "sweeep: unknown key; did you mean 'sweep'?" in text
    assert "objects[0].size: unknown key; did you mean 'size_m'?" in text
    assert "objects[0].params.trajectories.curve_angel" in text and "did you mean trajectories.curve_angle" in text


def test_wrong_types_and_bad_domains_name_the_key_path(tmp_path, ball):
    data = manifest(ball, seed="seven")
    data["objects"][0]["size_m"] = "big"
    data["objects"][0]["params"] = {"drips": {"drip_limit": 120}}
    data["sweep"] = {"method": "grid", "parameters": {"drips.count": {"values": [4, -1]}}}
    text = problems(tmp_path, data)
    assert "seed: expected an integer >= 0" in text
    assert "objects[0].size_m: expected the object's height in meters" in text
    assert "objects[0].params.drips.drip_limit" in text and "out of its domain ]1, 90[" in text
    assert "sweep.parameters.drips.count.values[1]" in text
    assert "4 problems" in text


def test_missing_files_are_reported(tmp_path, ball):
    data = manifest(ball, render="configs/nope.yaml")
    data["objects"].append({"id": "gone", "mesh": "missing.obj", "size_m": 1.0,
                            "overrides": {"drips": "edited.json", "surface": "x.ply"}})
    text = problems(tmp_path, data)
    assert f"objects[1].mesh: mesh file not found: {tmp_path / 'missing.obj'}" in text
    assert "objects[1].overrides.drips: file not found" in text
    assert "objects[1].overrides.surface: unknown key" in text
    assert "render: render config file not found" in text


def test_render_config_and_material_are_checked(tmp_path, ball):
    data = manifest(ball, render="previwe")
    data["objects"][0]["material"] = {"colour": [1, 1, 1]}
    text = problems(tmp_path, data)
    assert "render: render config 'previwe'" in text and "did you mean 'preview'?" in text
    assert "objects[0].material: material: unknown key 'colour'; did you mean 'color'?" in text


def test_generators_and_ids(tmp_path, ball):
    data = manifest(ball)
    data["objects"] += [{"mesh": "generator:fountian", "size_m": 0.5}, {"id": "ball", "mesh": ball.name, "size_m": 1}]
    text = problems(tmp_path, data)
    assert "unknown generator 'fountian'; did you mean generator:fountain?" in text
    assert "objects[2].id: 'ball' is used by an earlier object" in text
    data["objects"] = data["objects"][:2]
    data["objects"][1]["mesh"] = "generator:fountain"
    m = load_manifest(write(tmp_path, data))
    assert m.objects[1].id == "fountain" and m.objects[1].mesh == "generator:fountain"


def test_sweep_shape_errors(tmp_path, ball):
    bad = [
        ({"method": "grd", "parameters": {"drips.count": {"values": [1]}}},
         "sweep.method: expected one of grid, zip, random"),
        ({"method": "random", "parameters": {"drips.count": {"values": [1, 2]}}},
         "sweep.count: a random sweep needs count"),
        ({"method": "grid", "parameters": {"surface.noise": {"min": 0, "max": 1}}},
         "min/max ranges are drawn only by method: random"),
        ({"method": "zip",
          "parameters": {"drips.count": {"values": [1, 2]}, "surface.noise": {"values": [0, 0.1, 0.2]}}},
         "a zip sweep needs value lists of one length"),
        ({"method": "random", "count": 2,
          "parameters": {"surface.noise": {"min": 0, "max": 1, "distribution": "log_uniform"}}},
         "log_uniform needs min > 0"),
        ({"method": "random", "count": 2,
          "parameters": {"surface.noise": {"min": 0, "max": 1, "distribution": "normal"}}},
         "distribution: expected uniform or log_uniform"),
    ]
    for sweep, expected in bad:
        assert expected in problems(tmp_path, manifest(ball, sweep=sweep)), sweep


def test_grid_zip_random_expansion(tmp_path, ball):
    grid = load_manifest(write(tmp_path, manifest(ball, sweep={"method": "grid", "parameters": {
        "trajectories": {"curve_angle": {"values": [0, 5, 10]}},
        "surface.ripple_amplitude": {"values": [0.0, 0.001]}}})))
    points = expand(grid.sweep)
    assert len(points) == 6 and points[0] == {"trajectories.curve_angle": 0.0, "surface.ripple_amplitude": 0.0}
    assert points[1] == {"trajectories.curve_angle": 0.0, "surface.ripple_amplitude": 0.001}
    assert len({tuple(p.values()) for p in points}) == 6

    zipped = load_manifest(write(tmp_path, manifest(ball, sweep={"method": "zip", "parameters": {
        "drips.count": {"values": [4, 8, 16]}, "surface.mode": {"value": "tubes"}}})))
    assert expand(zipped.sweep) == [{"drips.count": n, "surface.mode": "tubes"} for n in (4, 8, 16)]

    rand = load_manifest(write(tmp_path, manifest(ball, sweep={"method": "random", "count": 20, "parameters": {
        "surface.noise": {"min": 0.0001, "max": 0.01, "distribution": "log_uniform"},
        "drips.count": {"min": 2, "max": 9},
        "surface.mode": {"values": ["tubes", "metaballs"]}}})))
    assert rand.sweep.axes[0].distribution is Distribution.LOG_UNIFORM
    a, b, c = expand(rand.sweep, 1), expand(rand.sweep, 1), expand(rand.sweep, 2)
    assert len(a) == 20 and a == b and a != c
    assert all(0.0001 <= p["surface.noise"] <= 0.01 for p in a)
    assert all(isinstance(p["drips.count"], int) and 2 <= p["drips.count"] <= 9 for p in a)
    assert {p["surface.mode"] for p in a} == {"tubes", "metaballs"}
    assert expand(None) == [{}]


def test_command_line_sets(tmp_path, ball):
    assert split_values("1,[0,-1,0],tubes") == ["1", "[0,-1,0]", "tubes"]
    assert parse_set("water.gravity=[0,0,-1]") == ("water.gravity", ([0.0, 0.0, -1.0],))
    assert parse_set("drips.count=4,8") == ("drips.count", (4, 8))
    with pytest.raises(InputError, match="did you mean drips.count"):
        parse_set("drips.cont=4")
    with pytest.raises(InputError, match="out of its domain"):
        parse_set("drips.count=4,-2")

    m = load_manifest(write(tmp_path, manifest(ball, sweep={"method": "zip", "parameters": {
        "drips.count": {"values": [4, 8]}, "surface.noise": {"values": [0.0, 0.001]}}})))
    m2 = apply_sets(m, ["trajectories.curve_angle=0,10,20", "surface.noise=0.002"])
    assert m2.fixed == {"surface.noise": 0.002}
    assert swept_keys(m2.sweep) == ("drips.count", "trajectories.curve_angle")
    points = expand(m2.sweep)
    assert len(points) == 6 and points[-1] == {"drips.count": 8, "trajectories.curve_angle": 20.0}
    assert m2.sweep.method is SweepMethod.ZIP

    plain = load_manifest(write(tmp_path, manifest(ball)))
    swept = apply_sets(plain, ["drips.count=1,2"])
    assert swept.sweep.method is SweepMethod.GRID and len(expand(swept.sweep)) == 2


def test_shipped_scenes_validate():
    paths = sorted(SCENES.glob("*.yaml"))
    assert any(p.name == "demo.yaml" for p in paths)
    for path in paths:
        m = load_manifest(path)
        assert m.objects and m.name


@pytest.mark.parametrize("bad", ["ball\n", "bäll", "_ball", "ball/x"])
def test_folder_names_must_match_whole(tmp_path, ball, bad):
    data = manifest(ball)
    data["objects"][0]["id"] = bad
    assert "objects[0].id: expected a folder-safe name (ASCII letters" in problems(tmp_path, data)
    data = manifest(ball, name=bad)
    assert "name: expected a folder-safe name" in problems(tmp_path, data)
