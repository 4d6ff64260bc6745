"""What a user hands icefarm reads as they meant it: numbers in any notation, text with a
byte-order mark, compressed glTF, reused and full and read-only folders."""

from __future__ import annotations

import pytest

from icefarm.farm.manifest import load_manifest
from icefarm.farm.points import parse_set
from icefarm.yaml_io import load_yaml


# ---------------------------------------------------------------- numbers
@pytest.mark.parametrize("text, value", [("5e-2", 0.05), ("1E3", 1000.0), ("-2.5e+3", -2500.0),
                                         ("1.5e3", 1500.0), (".5", 0.5), ("3", 3), ("1_000", 1000)])
def test_numbers_in_any_notation_read_as_numbers(text, value):
    assert load_yaml(text) == value and type(load_yaml(text)) is type(value)


@pytest.mark.parametrize("text", ["1e", "e5", "1e-2x", "0.1.2", "tubes"])
def test_text_that_only_looks_like_a_number_stays_text(text):
    assert load_yaml(text) == text


def test_set_and_manifest_take_scientific_notation(tmp_path, ball):
    assert parse_set("drips.spacing=5e-2") == ("drips.spacing", (0.05,))
    assert parse_set("drips.spacing=5e-2,1e-1") == ("drips.spacing", (0.05, 0.1))
    path = tmp_path / "m.yaml"
    path.write_text(f"name: t\nrender: null\ndefaults: {{drips.spacing: 5e-2}}\n"
                    f"objects:\n  - {{id: ball, mesh: {ball.name}, size_m: 3e-1}}\n")
    m = load_manifest(path)
    assert m.defaults == {"drips.spacing": 0.05} and m.objects[0].size_m == 0.3
