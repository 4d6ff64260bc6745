"""What a newcomer meets in the first hour: knobs the storm ignores, sizes in the wrong unit,
figures that say when they are off, sweeps that report what ran."""

import json

import pytest
import yaml
from click.testing import CliRunner

from icefarm import params
from icefarm.asset_io import size_hint
from icefarm.cli import main
from icefarm.cli.summary import verdict


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_knobs_of_the_other_storm_mode_are_named_with_what_to_use_instead():
    lines = params.idle_keys(["drips.count", "glaze.scale", "drips.spacing", "storm.wind"], "physical")
    assert len(lines) == 2
    assert "drips.count" in lines[0] and "drips.spacing" in lines[0] and "storm.mode=relative" in lines[0]
    assert "glaze.scale" in lines[1] and "storm.intensity" in lines[1]
    relative = params.idle_keys(["drips.count", "storm.wind", "surface.face_budget"], "relative")
    assert [line.split()[0] for line in relative] == ["storm.wind", "surface.face_budget"]
    rows = {f"{r['group']}.{r['name']}": r["mode"] for r in json.loads(run("params", "--json").output)}
    assert rows["drips.count"] == rows["glaze.scale"] == "relative"
    assert rows["storm.intensity"] == "physical" and rows["drips.spacing"] == "both"
    listed = run("params").output.splitlines()
    assert any(line.startswith("drips.count") and " relative " in line for line in listed)


def test_run_warns_once_about_a_knob_its_storm_ignores(tmp_path):
    result = CliRunner().invoke(main, ["run", "generator:sign", "--until", "water",
                                                       "--set", "drips.count=5", "-o", str(tmp_path / "j")])
    assert result.exit_code == 0, result.output
    assert result.stderr.count("warning: drips.count does nothing under storm.mode physical") == 1
    assert "drips.count" not in result.stdout
    quiet = CliRunner().invoke(main, [
        "run", "generator:sign", "--until", "water", "--set", "drips.count=5", "--set", "storm.mode=relative",
        "-o", str(tmp_path / "k")])
    assert quiet.exit_code == 0 and "warning" not in quiet.stderr


def test_validate_and_sweep_warn_about_ignored_knobs_and_unlikely_sizes(tmp_path):
    manifest = tmp_path / "m.yaml"
    manifest.write_text(yaml.safe_dump({
        "name": "t", "seed": 1, "render": None, "defaults": {"drips": {"count": 16}},
        "objects": [{"id": "cow", "mesh": "generator:teapot", "size_m": 600}],
        "sweep": {"method": "grid", "parameters": {"glaze.scale": {"values": [0.01, 0.02]}}}}))
    result = CliRunner().invoke(main, ["validate", str(manifest)])
    assert result.exit_code == 0 and "valid" in result.stdout
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 3, result.stderr
    assert "drips.count" in warnings[0] and "glaze.scale" in warnings[1]
    assert "object cow: size 600 m" in warnings[2] and "0.6" in warnings[2]
    dry = CliRunner().invoke(main, ["sweep", str(manifest), "-o", str(tmp_path / "out"),
                                                    "--dry-run", "--set", "storm.mode=relative"])
    assert dry.exit_code == 0, dry.output
    assert "drips.count" not in dry.stderr and "storm.mode" not in dry.stderr and "size 600 m" in dry.stderr


def test_a_size_that_cannot_be_is_a_usage_error_and_an_unlikely_one_a_hint(tmp_path):
    for size in ("-1", "0", "nan", "inf"):
        result = run("run", "generator:sign", "--size-m", size, "-o", tmp_path / "j")
        assert result.exit_code == 2 and "--size-m" in result.output, (size, result.output)
        assert not (tmp_path / "j").exists()
    assert "0.6" in size_hint(600) and "centimetres" in size_hint(600)
    assert "mm" in size_hint(0.004)
    assert size_hint(0.3) is size_hint(2.5) is size_hint(40) is None


@pytest.mark.parametrize("key, value, words", [
    ("growth_ratio", 0.25, "above the real range: a lighter storm.intensity"),
    ("growth_ratio", 0.01, "below the real range: surface.growth_ratio up"),
    ("taper", 2.1, "below the real range"),
    ("taper", 2.8, ""),  # within the measuring slack
    ("growth_ratio", 0.132, ""),
    ("fringe_free_share", 0.5, "drips.spacing up"),
    ("growth_ratio", 0.1, ""),
    ("taper", 5.0, ""),
    ("profile_exponent", 0.75, ""),
])
def test_a_figure_outside_its_real_range_says_which_knob_moves_it(key, value, words):
    said = verdict(key, value)
    assert (words in said) if words else said == ""


def test_render_again_defaults_to_lookdev_not_a_ten_minute_final():
    from icefarm.cli.main import render_command

    option = next(p for p in render_command.params if p.name == "render")
    assert option.default == "lookdev"


def test_a_sweep_over_the_icicles_look_without_an_ice_view_says_to_use_lookdev(tmp_path):
    manifest = tmp_path / "m.yaml"
    sweep = {"method": "grid", "parameters": {"surface.growth_ratio": {"values": [0.03, 0.06]}}}
    for render, warned in (("preview", True), ("lookdev", False)):
        manifest.write_text(yaml.safe_dump({"name": "t", "seed": 1, "render": render, "sweep": sweep,
                                            "objects": [{"id": "sign", "mesh": "generator:sign"}]}))
        result = CliRunner().invoke(main, ["validate", str(manifest)])
        assert result.exit_code == 0
        assert ("has no ice view" in result.stderr and "render: lookdev" in result.stderr) is warned


def test_run_reads_a_shared_cache_it_may_not_write(tmp_path, monkeypatch):
    import os

    import icefarm.job.cache as stage_cache

    cache = tmp_path / "cache"
    first = run("run", "generator:sign", "--until", "water", "--cache", cache, "-o", tmp_path / "a")
    assert first.exit_code == 0 and any(cache.rglob("*")), first.output
    stored = sorted(p.name for p in cache.rglob("*") if p.is_file())
    real = os.access  # as root every folder is writable: the cache is made read-only here
    monkeypatch.setattr(stage_cache.os, "access", lambda path, mode: not (mode & os.W_OK) and real(path, mode))
    again = CliRunner().invoke(main, ["run", "generator:sign", "--until", "drips", "--cache", str(cache),
                                      "-o", str(tmp_path / "b")])
    assert again.exit_code == 0, again.output
    assert again.stderr.count("is read-only: its results are reused") == 1
    assert sorted(p.name for p in cache.rglob("*") if p.is_file()) == stored  # nothing stored
    assert "water" in json.loads((tmp_path / "b" / "done.json").read_text())["reused"]


def test_still_air_is_one_setting_in_a_sweep_as_in_a_run():
    from icefarm.farm.points import parse_set

    assert parse_set("storm.wind=0,0,0") == ("storm.wind", ([0.0, 0.0, 0.0],))
    assert parse_set("storm.wind=[0,0,0],[0,0,-5]")[1] == ([0.0, 0.0, 0.0], [0.0, 0.0, -5.0])
    assert parse_set("drips.spacing=0.02,0.03")[1] == (0.02, 0.03)


def test_a_job_stopped_before_its_drips_says_nothing_of_icicles(tmp_path):
    result = run("run", "generator:sign", "--until", "water", "-o", tmp_path / "j")
    assert result.exit_code == 0 and "storm: moderate freezing rain" in result.stdout
    assert "icicles" not in result.stdout and "warning" not in result.stdout
