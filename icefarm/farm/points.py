"""The points of a sweep: `--set` values on a manifest, counting, and expansion.

A manifest's ``sweep`` (grid, random or zip over parameter axes) becomes the list of
parameter assignments its jobs run; `apply_sets` folds command-line ``--set`` values in
first, and the job count is checked before anything is expanded.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from .. import params as P
from ..errors import InputError
from .manifest import SOURCE_KEY, source_problems
from .manifest_model import Axis, Distribution, Manifest, Sweep, SweepMethod

MAX_JOBS = 10_000  # a sweep of more jobs is refused unless --max-jobs raises the limit


def split_values(text: str) -> list[str]:
    """Split ``a,b,[1,2,3]`` at the commas outside brackets (Hydra's sweep syntax)."""
    parts, depth, current = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in ")]":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append("".join(current))
            current = []
        else:
            current.append(ch)
    parts.append("".join(current))
    return [p.strip() for p in parts]


def parse_set(text: str) -> tuple[str, tuple]:
    """``"group.param=v1,v2"`` to ``(key, (v1, v2))``, every value validated. A vector's
    three numbers are one value (``storm.wind=0,0,0``); vectors swept are bracketed
    (``storm.wind=[0,0,0],[0,0,-5]``).

    Raises
    ------
    InputError
        No ``=``, an unknown parameter (with the nearest one), an empty or out-of-domain value.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--set {text!r}: expected group.param=value or group.param=v1,v2,...")
    param = P.lookup(key.strip())
    items = split_values(raw)
    if param.kind is P.Kind.VECTOR and len(items) == 3 and not any(i.startswith("[") for i in items):
        items = [raw]  # storm.wind=0,0,0 is one vector, as `icefarm run --set` reads it; [..],[..] sweeps
    if any(not item for item in items):
        raise InputError(f"--set {text!r}: empty value; give group.param=value or a comma list")
    values = tuple(param.validate(P.parse_value(item)) for item in items)
    if len({repr(v) for v in values}) != len(values):
        raise InputError(f"--set {text!r}: a value is listed twice")
    return param.key, values


def apply_sets(manifest: Manifest, sets: Sequence[str]) -> Manifest:
    """Apply command-line ``--set`` assignments to ``manifest``.

    A single value fixes the parameter for every job (over the defaults, the objects' params
    and the sweep); a comma list sweeps it: it replaces or joins a grid sweep's parameters, and
    is crossed with the points of a zip or random sweep.
    """
    sweep, fixed = manifest.sweep, dict(manifest.fixed)
    for text in sets:
        key, values = parse_set(text)
        if sweep is not None:
            sweep = replace(sweep, axes=tuple(a for a in sweep.axes if a.key != key),
                            product=tuple(a for a in sweep.product if a.key != key))
        if len(values) == 1:
            fixed[key] = values[0]
            continue
        fixed.pop(key, None)
        axis = Axis(key=key, values=values)
        old_axes = [a.key for a in manifest.sweep.axes] if manifest.sweep else []
        if sweep is None:
            sweep = Sweep(method=SweepMethod.GRID, axes=(axis,))
        elif sweep.method is SweepMethod.GRID:
            axes = list(sweep.axes)
            # Keep the manifest's order when the key was already swept there.
            at = old_axes.index(key) if key in old_axes else len(axes)
            axes.insert(min(at, len(axes)), axis)
            sweep = replace(sweep, axes=tuple(axes))
        else:
            sweep = replace(sweep, product=sweep.product + (axis,))
    if sweep is not None and not sweep.axes and not sweep.product:
        sweep = None
    out = replace(manifest, sweep=sweep, fixed=fixed)
    if any(text.partition("=")[0].strip() in (SOURCE_KEY, "source") for text in sets):
        problems = source_problems(out)
        if problems:
            raise InputError(f"{manifest.path}: --set: " + "; ".join(problems))
    return out


def swept_keys(sweep: Sweep | None) -> tuple[str, ...]:
    """The swept parameters, in the order jobs.csv lists them."""
    if sweep is None:
        return ()
    return tuple(a.key for a in sweep.axes) + tuple(a.key for a in sweep.product)


def count_points(sweep: Sweep | None) -> int:
    """How many points `expand` gives, counted without making them."""
    if sweep is None:
        return 1
    if sweep.method is SweepMethod.GRID:
        n = math.prod(len(a.values) for a in sweep.axes)
    elif sweep.method is SweepMethod.ZIP:
        n = max((len(a.values) for a in sweep.axes), default=1)
    else:
        n = sweep.count or 0
    return n * math.prod(len(a.values) for a in sweep.product)


def count_jobs(manifest: Manifest) -> int:
    """Jobs of the manifest (objects times sweep points; repeated points still counted)."""
    return len(manifest.objects) * count_points(manifest.sweep)


def check_job_count(manifest: Manifest, max_jobs: int | None = MAX_JOBS) -> int:
    """The manifest's job count; refused past ``max_jobs`` before anything is expanded.

    Raises
    ------
    InputError
        More jobs than ``max_jobs`` (a 10^10-point grid, a random sweep with count 1e9).
    """
    n = count_jobs(manifest)
    if max_jobs is not None and n > max_jobs:
        points = count_points(manifest.sweep)
        raise InputError(f"{manifest.path}: the sweep makes {n:,} jobs ({len(manifest.objects)} object(s) x "
                         f"{points:,} point(s)), more than the limit of {max_jobs:,}: shrink the sweep, "
                         f"or raise the limit with --max-jobs {n} if you mean it")
    return n


def expand(sweep: Sweep | None, seed: int = 0) -> list[dict[str, Any]]:
    """The sweep's points, each ``{"group.name": value}``; ``[{}]`` when there is no sweep.

    Grid: every combination, the last parameter varying fastest. Zip: the i-th value of each
    parameter (one-value lists repeat). Random: ``count`` points drawn with a generator seeded
    by ``seed`` (the same seed gives the same points); lists are drawn from uniformly, ranges by
    their distribution, integers rounded, floats kept to 6 significant digits.
    The command line's crossed parameters (``sweep.product``) multiply these points as a grid.
    """
    if sweep is None:
        return [{}]
    axes = sweep.axes
    if sweep.method is SweepMethod.GRID:
        points = [dict(zip([a.key for a in axes], combo)) for combo in itertools.product(*(a.values for a in axes))]
    elif sweep.method is SweepMethod.ZIP:
        n = max((len(a.values) for a in axes), default=1)
        points = [{a.key: a.values[i if len(a.values) > 1 else 0] for a in axes} for i in range(n)]
    else:
        rng = np.random.default_rng([seed, 0x5EED])
        points = [{a.key: _draw(a, rng) for a in axes} for _ in range(sweep.count or 0)]
    if sweep.product:
        keys = [a.key for a in sweep.product]
        crossed = [dict(zip(keys, combo)) for combo in itertools.product(*(a.values for a in sweep.product))]
        points = [{**p, **c} for p in points for c in crossed]
    return points


def _draw(axis: Axis, rng: np.random.Generator) -> Any:
    param = P.lookup(axis.key)
    if axis.values:
        return axis.values[int(rng.integers(len(axis.values)))]
    lo, hi = axis.low, axis.high
    if axis.distribution is Distribution.LOG_UNIFORM:
        x = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    else:
        x = rng.uniform(lo, hi)
    if param.kind is P.Kind.INT:
        x = int(min(max(round(x), math.ceil(lo)), math.floor(hi)))
    else:
        x = min(max(float(f"{x:.6g}"), lo), hi)
    return param.validate(x)
