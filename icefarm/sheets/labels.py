"""Which parameters vary, and how their names and values are written on a sheet."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .. import params as P
from .model import JobInfo

# parameters

def canonical(value: Any) -> str:
    """A comparable form of a parameter value (1 == 1.0; lists by their items)."""
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, (int, float)):
        return repr(float(value))
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(canonical(v) for v in value) + "]"
    return repr(value)


def sort_key(value: Any) -> tuple:
    if value is None:
        return (3, "")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return (0, float(value))
    if isinstance(value, (list, tuple)):
        return (2, tuple(sort_key(v) for v in value))
    return (1, str(value))


def varying_keys(jobs: Sequence[JobInfo], order: Sequence[str] = ()) -> list[str]:
    """Parameters whose value differs between the jobs, in ``order`` then Table 1 order.

    A key missing from some jobs (an older params.yaml) counts as varying only if the jobs
    that have it disagree.
    """
    seen: dict[str, set] = {}
    for job in jobs:
        for key, value in job.values.items():
            seen.setdefault(key, set()).add(canonical(value))
    keys = [k for k, v in seen.items() if len(v) > 1]
    rank = {k: i for i, k in enumerate(order)}
    table = {k: i for i, k in enumerate(P.param_index())}
    return sorted(keys, key=lambda k: (rank.get(k, len(rank)), table.get(k, len(table)), k))


def fixed_changes(jobs: Sequence[JobInfo], varying: Sequence[str]) -> dict[str, Any]:
    """Parameters shared by all the jobs that differ from `icefarm.params.defaults`."""
    defaults = P.flatten(P.defaults())
    with_params = [j for j in jobs if j.has_params]
    if not with_params:
        return {}
    out = {}
    for key, value in with_params[0].values.items():
        if key in varying or any(canonical(j.values.get(key)) != canonical(value) for j in with_params[1:]):
            continue
        if key not in defaults or canonical(defaults[key]) != canonical(value):
            out[key] = value
    return out


def _unique_names() -> set[str]:
    names = [p.name for p in P.PARAMS]
    return {n for n in names if names.count(n) == 1}


def short_name(key: str) -> str:
    """``trajectories.curve_angle`` -> ``curve_angle`` where the name alone is unambiguous."""
    group, _, name = key.rpartition(".")
    return name if group and name in _unique_names() else key


def format_value(key: str, value: Any) -> str:
    """A value with its unit: ``2 deg``, ``0.004 m``, ``tubes``, ``0 -1 0``."""
    if isinstance(value, (list, tuple)):
        text = " ".join(format_value("", v) for v in value)
    elif isinstance(value, float):
        text = f"{value:.6g}"
    else:
        text = str(value)
    param = P.param_index().get(key)
    if param is not None and param.unit not in ("-", "") and not isinstance(value, (list, tuple, str)):
        text += f" {param.unit}"
    return text


def assignment(key: str, value: Any) -> str:
    return f"{short_name(key)}={format_value(key, value)}"


def compact_assignment(key: str, value: Any) -> str:
    """``c=2``: the paper's symbol where it names one parameter, no unit (the header has them)."""
    param = P.param_index().get(key)
    symbols = [p.symbol for p in P.PARAMS]
    name = param.symbol if param is not None and param.symbol != "-" and symbols.count(param.symbol) == 1 \
        else short_name(key)
    return f"{name}={format_value('', value)}"


def axis_title(key: str) -> str:
    param = P.param_index().get(key)
    if param is None:
        return key
    bits = [b for b in (param.symbol if param.symbol != "-" else "", param.unit if param.unit != "-" else "") if b]
    return f"{key} ({', '.join(bits)})" if bits else key
