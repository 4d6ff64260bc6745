"""Value checks for render config keys (and the object material's, `material`).

Each check takes ``(key, value)`` and returns the coerced value or raises `InputError`
naming the key, the value and what was expected; `number_check`, `choice_check` and `triple_check` build
checks, the others are checks themselves.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import InputError


def refusal(key: str, value: Any, expected: str) -> InputError:
    return InputError(f"render config: {key} = {value!r} is not valid: expected {expected}")


def number_check(low=None, high=None, integer=False, low_open=False) -> Callable[[str, Any], Any]:
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    expected = f"{'an integer' if integer else 'a number'} in {'(' if low_open else '['}{lo}, {hi}]"

    def check(key, value):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise refusal(key, value, expected)
        if integer and float(value) != int(value):
            raise refusal(key, value, expected)
        value = int(value) if integer else float(value)
        if not math.isfinite(value) or (low is not None and (value < low or (low_open and value == low))) \
                or (high is not None and value > high):
            raise refusal(key, value, expected)
        return value

    return check


def choice_check(choices: Sequence[str]) -> Callable[[str, Any], str]:
    def check(key, value):
        if value not in choices:
            hint = difflib.get_close_matches(str(value), choices, n=1, cutoff=0.5)
            tip = f" (did you mean {hint[0]!r}?)" if hint else ""
            raise refusal(key, value, "one of " + " | ".join(choices) + tip)
        return value

    return check


def triple_check(low: float, high: float,
                 expected: str | None = None) -> Callable[[str, Any], tuple[float, float, float]]:
    expected = expected or f"3 numbers in [{low:g}, {high:g}]"

    def check(key, value):
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 3:
            raise refusal(key, value, expected)
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not low <= v <= high:
                raise refusal(key, value, expected)
            out.append(float(v))
        return tuple(out)

    return check


def check_resolution(key, value):
    expected = "[width, height], integers in [8, 16384]"
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise refusal(key, value, expected)
    if not all(isinstance(v, int) and not isinstance(v, bool) and 8 <= v <= 16384 for v in value):
        raise refusal(key, value, expected)
    return (int(value[0]), int(value[1]))


def check_sky(key, value):
    if not isinstance(value, str) or not value:
        raise refusal(key, value, "'procedural' or the path of an equirectangular .exr/.hdr image")
    if value == "procedural":
        return value
    path = Path(value).expanduser()
    if path.suffix.lower() not in (".exr", ".hdr"):
        raise refusal(key, value, "'procedural' or the path of an equirectangular .exr/.hdr image")
    if not path.is_file():
        raise InputError(f"render config: environment.sky = {value!r}: no such file")
    return str(path.resolve())


MAX_ABSORPTION = 1.0e4  # per meter: light through 1 mm of ice keeps e^-10


def check_absorption(key, value):
    """Per-meter coefficients ``[r, g, b]`` (or one number for all three), or the colour
    white light takes after a distance of ice, ``{color: [r, g, b], distance: m}``."""
    expected = (f"[r, g, b] absorption per meter, each in [0, {MAX_ABSORPTION:g}], or "
                "{color: [r, g, b] in (0, 1], distance: meters > 0}: the colour white light "
                "takes after that distance of ice")
    if isinstance(value, Mapping):
        if set(value) != {"color", "distance"}:
            raise refusal(key, value, expected)
        color, distance = value["color"], value["distance"]
        if isinstance(distance, bool) or not isinstance(distance, (int, float)) \
                or not math.isfinite(distance) or distance <= 0:
            raise refusal(key, value, expected)
        if isinstance(color, (str, bytes)) or not isinstance(color, Sequence) or len(color) != 3 or not all(
                not isinstance(c, bool) and isinstance(c, (int, float)) and 0.0 < c <= 1.0 for c in color):
            raise refusal(key, value, expected)
        per_m = tuple(-math.log(float(c)) / float(distance) + 0.0 for c in color)
        if max(per_m) > MAX_ABSORPTION:
            raise refusal(key, value, expected)
        return per_m
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    return triple_check(0.0, MAX_ABSORPTION, expected)(key, value)
