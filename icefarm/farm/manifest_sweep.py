"""The ``sweep`` section of a manifest: its method and the axes (swept parameters) it varies.

As in `icefarm.farm.manifest_objects`, every problem found is appended to ``errors``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .. import params as P
from ..errors import InputError, short_repr
from .manifest_model import Axis, Distribution, Sweep, SweepMethod
from .manifest_yaml import MAX_VALUE_ITEMS, describe, too_big, unknown_keys

SWEEP_KEYS = ("method", "count", "parameters")
AXIS_KEYS = ("values", "value", "min", "max", "distribution")


def parse_sweep(value: Any, errors: list[str]) -> Sweep | None:
    """The ``sweep`` mapping (method, count, parameters); None when it cannot be read."""
    if not isinstance(value, Mapping):
        errors.append(f"sweep: expected a mapping with keys {', '.join(SWEEP_KEYS)}, got {describe(value)}")
        return None
    unknown_keys(value, SWEEP_KEYS, "sweep", errors)
    raw_method = value.get("method", "grid")
    try:
        method = SweepMethod(raw_method)
    except ValueError:
        errors.append(f"sweep.method: expected one of grid, zip, random, got {short_repr(raw_method)}")
        return None
    count = value.get("count")
    if method is SweepMethod.RANDOM:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            errors.append(f"sweep.count: a random sweep needs count, an integer >= 1, got {describe(count)}")
            count = None
    elif count is not None:
        errors.append(f"sweep.count: only a random sweep takes a count; a {method.value} sweep's size "
                      f"comes from its values")
    parameters = value.get("parameters")
    if not isinstance(parameters, Mapping) or not parameters:
        errors.append(f"sweep.parameters: expected a mapping group.param: {{values: [...]}} or {{min, max}}, "
                      f"got {describe(parameters)}")
        return None
    axes = []
    for key, spec in _flat_axes(parameters, errors):
        axis = parse_axis(key, spec, method, f"sweep.parameters.{key}", errors)
        if axis is not None:
            axes.append(axis)
    if method is SweepMethod.ZIP:
        lengths = {len(a.values) for a in axes if len(a.values) > 1}
        if len(lengths) > 1:
            detail = ", ".join(f"{a.key}: {len(a.values)}" for a in axes)
            errors.append(f"sweep.parameters: a zip sweep needs value lists of one length, got {detail}")
    sweep = Sweep(method=method, axes=tuple(axes), count=count if method is SweepMethod.RANDOM else None)
    _check_duplicate_axes(sweep, errors)
    return sweep


def _flat_axes(parameters: Mapping, errors: list[str]) -> list[tuple[str, Any]]:
    """Sweep parameters as flat ``group.name`` keys; ``{group: {name: {values: ...}}}`` nests too."""
    out = []
    for key, spec in parameters.items():
        if key in P.GROUPS and isinstance(spec, Mapping) and not set(spec) & set(AXIS_KEYS):
            out.extend((f"{key}.{name}", s) for name, s in spec.items())
        else:
            out.append((str(key), spec))
    return out


def parse_axis(key: str, spec: Any, method: SweepMethod, where: str, errors: list[str]) -> Axis | None:
    """One sweep parameter ``{values: [...]}``, ``{value: x}`` or ``{min, max, distribution}``."""
    try:
        param = P.lookup(key)
    except InputError as exc:
        errors.append(f"{where}: {exc}")
        return None
    if not isinstance(spec, Mapping):
        errors.append(f"{where}: expected {{values: [...]}} or {{min: a, max: b}}, got {describe(spec)}")
        return None
    unknown_keys(spec, AXIS_KEYS, where, errors)
    if "values" in spec or "value" in spec:
        raw = spec.get("values", [spec.get("value")] if "value" in spec else None)
        if not isinstance(raw, list) or not raw:
            errors.append(f"{where}.values: expected a non-empty list of values, got {describe(raw)}")
            return None
        if too_big(raw):
            errors.append(f"{where}.values: more than {MAX_VALUE_ITEMS:,} items (nested YAML aliases?): "
                          "list the values one by one")
            return None
        values = []
        for i, v in enumerate(raw):
            try:
                values.append(param.validate(v))
            except InputError as exc:
                errors.append(f"{where}.values[{i}]: {exc}")
        if len({repr(v) for v in values}) != len(values):
            errors.append(f"{where}.values: a value is listed twice: {short_repr(raw)}")
        return Axis(key=param.key, values=tuple(values))
    if "min" not in spec or "max" not in spec:
        errors.append(f"{where}: expected values: [...] or both min and max")
        return None
    if method is not SweepMethod.RANDOM:
        errors.append(f"{where}: min/max ranges are drawn only by method: random; "
                      f"a {method.value} sweep needs values: [...]")
        return None
    if param.kind not in (P.Kind.INT, P.Kind.FLOAT):
        errors.append(f"{where}: {param.key} is not a number; list its values instead")
        return None
    if too_big(spec["min"]) or too_big(spec["max"]):
        errors.append(f"{where}: min and max must be numbers")
        return None
    try:
        low, high = param.validate(spec["min"]), param.validate(spec["max"])
    except InputError as exc:
        errors.append(f"{where}: {exc}")
        return None
    if not low < high:
        errors.append(f"{where}: expected min < max, got min {low} max {high}")
    raw_dist = spec.get("distribution", "uniform")
    try:
        dist = Distribution(raw_dist)
    except ValueError:
        errors.append(f"{where}.distribution: expected uniform or log_uniform, got {short_repr(raw_dist)}")
        return None
    if dist is Distribution.LOG_UNIFORM and low <= 0:
        errors.append(f"{where}: log_uniform needs min > 0, got {low}")
    return Axis(key=param.key, low=float(low), high=float(high), distribution=dist)


def _check_duplicate_axes(sweep: Sweep, errors: list[str]) -> None:
    keys = [a.key for a in sweep.axes]
    for key in {k for k in keys if keys.count(k) > 1}:
        errors.append(f"sweep.parameters.{key}: swept twice (once nested, once flat)")
