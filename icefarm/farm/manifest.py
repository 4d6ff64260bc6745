"""Read and validate a sweep manifest (YAML) before anything runs.

A manifest names the objects to ice, the parameters every object shares, and a sweep over
parameters in the shape of a W&B sweep config::

    name: demo
    seed: 7
    render: preview                 # a render_configs/ name, a path, or null for no render
    defaults: {surface: {mode: tubes}}
    objects:
      - id: fountain
        mesh: generator:fountain    # or a mesh file, relative to the manifest
        size_m: 0.3
        params: {drips.count: 12}
        exclude: [{min: [0, 0, 0], max: [0.1, 0.1, 0.1]}]
        overrides: {drips: edited_drips.json}
        material: {color: [0.8, 0.8, 0.8]}
        placement: ground          # or hanging (a sign, a branch, a lamp)
        growth: {frames: 24}       # also the ice at 24 moments of its growth (growth.frames)
    sweep:
      method: grid                  # grid | zip | random
      count: 8                      # random only
      parameters:
        trajectories.curve_angle: {values: [0, 5]}
        surface.ripple_amplitude: {min: 0.0001, max: 0.001, distribution: log_uniform}

Every problem found is reported at once, each naming the file, the key path and what was
expected; unknown keys come with the nearest valid one.
"""

from __future__ import annotations

import difflib
import enum
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .. import params as P
from ..errors import InputError, short_repr
from ..placement import PLACEMENTS

GENERATOR_PREFIX = "generator:"
OVERRIDE_STAGES = {"water": (".ply",), "drips": (".json",), "trajectories": (".json",)}
TOP_KEYS = ("name", "seed", "render", "defaults", "objects", "sweep")
OBJECT_KEYS = ("id", "mesh", "size_m", "placement", "params", "exclude", "overrides", "material", "growth")
SWEEP_KEYS = ("method", "count", "parameters")
AXIS_KEYS = ("values", "value", "min", "max", "distribution")
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class SweepMethod(enum.Enum):
    GRID = "grid"      # every combination of the parameters' values
    ZIP = "zip"        # the i-th value of every parameter together
    RANDOM = "random"  # `count` points drawn at random


class Distribution(enum.Enum):
    UNIFORM = "uniform"
    LOG_UNIFORM = "log_uniform"  # min and max are values, as W&B's log_uniform_values


@dataclass(frozen=True)
class Axis:
    """One swept parameter: a list of values, or a range for random sweeps.

    Attributes
    ----------
    key : str
        ``group.name`` of the parameter.
    values : tuple
        Validated values (empty for a range).
    low, high : float or None
        The range for random draws, in the parameter's unit.
    distribution : Distribution or None
        How a range is drawn.
    """

    key: str
    values: tuple = ()
    low: float | None = None
    high: float | None = None
    distribution: Distribution | None = None


@dataclass(frozen=True)
class Sweep:
    """The sweep section: ``method`` over ``axes``; ``product`` axes (from ``--set a,b``)
    are crossed with the method's points as a grid."""

    method: SweepMethod
    axes: tuple[Axis, ...]
    count: int | None = None
    product: tuple[Axis, ...] = ()


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a manifest, with paths made absolute.

    Attributes
    ----------
    id : str
        Folder-safe name, unique in the manifest.
    mesh : str
        Absolute path of a mesh file, or ``generator:NAME``.
    size_m : float
        Height of the bounding box, in meters.
    params : dict
        Flat ``{"group.name": value}``, validated; over the manifest's defaults.
    exclude : tuple
        Boxes ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` in meters, object frame.
    overrides : tuple
        ``((stage, absolute path), ...)`` files replacing a stage's result.
    material : tuple
        ``((key, value), ...)`` for rendering.
    placement : str
        ``ground`` (stands on the ground plane) or ``hanging``.
    """

    id: str
    mesh: str
    size_m: float
    params: dict = field(default_factory=dict)
    exclude: tuple = ()
    overrides: tuple = ()
    material: tuple = ()
    placement: str = "ground"


@dataclass(frozen=True)
class Manifest:
    """A validated manifest. ``defaults`` and object ``params`` are flat ``{"group.name": v}``;
    ``fixed`` holds command-line overrides that win over everything else."""

    path: Path
    name: str
    seed: int
    render: str | None
    defaults: dict
    objects: tuple[ObjectSpec, ...]
    sweep: Sweep | None = None
    fixed: dict = field(default_factory=dict)


def load_manifest(path: str | Path) -> Manifest:
    """Read and validate the manifest at ``path``.

    Raises
    ------
    InputError
        The file is missing or not YAML, or it has problems: all of them are listed,
        each as ``FILE: key.path: what was expected``.
    """
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise InputError(f"manifest not found: {path}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read the manifest {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(f"{path}: not UTF-8 text: byte 0x{raw[exc.start]:02x} on line {line} "
                         f"(save the manifest as UTF-8)") from None
    try:
        data = yaml.load(text, Loader=StrictLoader)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from None
    return parse_manifest(data, path)


class StrictLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses a key given twice in one mapping (the plain loader
    keeps the last silently). Keys brought in by a merge (``<<: *base``) may be overridden."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.setdefault(key, key_node.start_mark)
                except TypeError:  # an unhashable key: the base class says so
                    continue
                if first is not key_node.start_mark:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping", node.start_mark,
                        f"found the key {short_repr(key)} twice (first on line {first.line + 1}); "
                        "a key may be given once", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


MAX_VALUE_ITEMS = 10_000  # a parameter value holding more items is refused (a YAML alias bomb)
MAX_ERRORS = 50  # problems listed one by one; the rest are counted


def too_big(value: Any, limit: int = MAX_VALUE_ITEMS) -> bool:
    """Whether ``value`` holds more than ``limit`` items in all, counted without expanding it:
    YAML aliases nest lists that a repr or a walk would take to billions of items."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > limit:
            return True
        if isinstance(item, Mapping):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple, set)):
            stack.extend(item)
    return False


def parse_manifest(data: Any, path: Path) -> Manifest:
    """Validate already-loaded manifest ``data``; relative paths are taken from ``path``'s folder."""
    errors: list[str] = []
    manifest = _parse(data, Path(path), errors)
    if errors:
        head = f"{path}: {len(errors)} problem{'s' if len(errors) > 1 else ''} in the manifest"
        more = [f"  ... and {len(errors) - MAX_ERRORS} more"] if len(errors) > MAX_ERRORS else []
        raise InputError(head + "\n" + "\n".join([f"  {path}: {e}" for e in errors[:MAX_ERRORS]] + more))
    return manifest


def _parse(data: Any, path: Path, errors: list[str]) -> Manifest | None:
    if not isinstance(data, Mapping):
        errors.append(f"(top): expected a mapping with keys {', '.join(TOP_KEYS)}, got {_kind(data)}")
        return None
    _unknown_keys(data, TOP_KEYS, "", errors)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not _ID.match(name):
        errors.append(f"name: expected a folder-safe name (letters, digits, _ . -), got {short_repr(name)}")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        errors.append(f"seed: expected an integer >= 0, got {short_repr(seed)}")
    render = _render(data.get("render"), path, errors)
    defaults = _params(data.get("defaults"), "defaults", errors)
    objects = _objects(data.get("objects"), path, errors)
    sweep = _sweep(data.get("sweep"), errors) if data.get("sweep") is not None else None
    if sweep is not None:
        _check_duplicate_axes(sweep, errors)
    if errors:
        return None
    # The defaults and each object's params must also resolve together (all in domain).
    for obj in objects:
        try:
            P.resolve(defaults, obj.params)
        except InputError as exc:
            errors.append(f"objects[{obj.id}]: {exc}")
    manifest = Manifest(path=path, name=name, seed=seed, render=render, defaults=defaults,
                        objects=tuple(objects), sweep=sweep)
    errors.extend(source_problems(manifest))
    return None if errors else manifest


SOURCE_KEY = "water.source"


def source_path(source: str, mesh: str) -> Path:
    """Where a job looks for its ``water.source`` mesh (as `icefarm.pipeline` does):
    a relative path is taken from the mesh file's folder (for a generator: the working folder)."""
    path = Path(source).expanduser()
    if not path.is_absolute() and not mesh.startswith(GENERATOR_PREFIX):
        path = Path(mesh).parent / path
    return path.resolve()


def source_problems(manifest: Manifest) -> list[str]:
    """Each ``water.source`` a job of ``manifest`` would use that names no file."""
    sweep = manifest.sweep
    swept = [v for a in ((sweep.axes + sweep.product) if sweep else ()) if a.key == SOURCE_KEY for v in a.values]
    problems = []
    for i, obj in enumerate(manifest.objects):
        fixed = manifest.fixed.get(SOURCE_KEY, obj.params.get(SOURCE_KEY, manifest.defaults.get(SOURCE_KEY)))
        for source in dict.fromkeys([fixed, *swept]):
            if isinstance(source, str) and source != "auto" and not source_path(source, obj.mesh).is_file():
                problems.append(f"objects[{i}] ({obj.id}): water.source {short_repr(source)}: no file at "
                                f"{source_path(source, obj.mesh)} (a relative path is taken from the mesh's folder)")
    return problems


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    return (f"{type(value).__name__} {short_repr(value)}" if not isinstance(value, (Mapping, list))
            else type(value).__name__)


def _join(where: str, key: Any) -> str:
    return f"{where}.{key}" if where else str(key)


def _unknown_keys(data: Mapping, allowed: tuple[str, ...], where: str, errors: list[str]) -> None:
    for key in data:
        if key in allowed:
            continue
        key = short_repr(key) if not isinstance(key, str) or len(key) > 60 else key
        hint = difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.5)
        tip = f"did you mean {hint[0]!r}?" if hint else f"expected one of {', '.join(allowed)}"
        errors.append(f"{_join(where, key)}: unknown key; {tip}")


def _render(value: Any, path: Path, errors: list[str]) -> str | None:
    """A render config name (render_configs/NAME.yaml) or a path; None/false means no render."""
    if value is None or value is False or value == "none":
        return None
    if not isinstance(value, str) or not value:
        errors.append(f"render: expected a render config name (e.g. preview) or a path, got {_kind(value)}")
        return None
    from ..scene.config import load_render_config

    if "/" in value or value.endswith((".yaml", ".yml")):
        value = str((path.parent / value).expanduser().resolve())
        if not Path(value).is_file():
            errors.append(f"render: render config file not found: {value}")
            return value
    try:
        load_render_config(value)
    except InputError as exc:
        errors.append(f"render: {exc}")
    return value


def generator_names() -> set[str] | None:
    """Names ``generator:NAME`` accepts, or None when the generators module cannot list them."""
    try:
        from .. import generators
    except ImportError:
        return None
    for attr in ("names", "available", "generator_names"):
        fn = getattr(generators, attr, None)
        if callable(fn):
            return set(fn())
    for attr in ("GENERATORS", "NAMES"):
        table = getattr(generators, attr, None)
        if table is not None:
            return set(table)
    return None


def _params(value: Any, where: str, errors: list[str]) -> dict[str, Any]:
    """Nested ``{group: {name: v}}`` or flat ``{"group.name": v}`` to validated flat keys."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        errors.append(f"{where}: expected a mapping of parameters (group.name: value), got {_kind(value)}")
        return {}
    flat: dict[str, Any] = {}
    for key, v in value.items():
        if isinstance(v, Mapping):
            if key not in P.GROUPS:
                hint = difflib.get_close_matches(str(key), P.GROUPS, n=1, cutoff=0.5)
                tip = f"did you mean {hint[0]!r}?" if hint else f"expected one of {', '.join(P.GROUPS)}"
                errors.append(f"{_join(where, key)}: unknown parameter group; {tip}")
                continue
            items = [(f"{key}.{name}", x) for name, x in v.items()]
        else:
            items = [(str(key), v)]
        for full, x in items:
            if too_big(x):
                errors.append(f"{_join(where, full)}: a value of more than {MAX_VALUE_ITEMS:,} items "
                              "(nested YAML aliases?): expected a number, a word or a short list")
                continue
            try:
                param = P.lookup(full)
                flat[param.key] = param.validate(x)
            except InputError as exc:
                errors.append(f"{_join(where, full)}: {exc}")
    return flat


def _objects(value: Any, path: Path, errors: list[str]) -> list[ObjectSpec]:
    if not isinstance(value, list) or not value:
        errors.append(f"objects: expected a non-empty list of objects (id, mesh, size_m, ...), got {_kind(value)}")
        return []
    out: list[ObjectSpec] = []
    seen: set[str] = set()
    for i, item in enumerate(value):
        where = f"objects[{i}]"
        if not isinstance(item, Mapping):
            errors.append(f"{where}: expected a mapping with keys id, mesh, size_m, ..., got {_kind(item)}")
            continue
        _unknown_keys(item, OBJECT_KEYS, where, errors)
        mesh = _mesh(item.get("mesh"), path, f"{where}.mesh", errors)
        default_id = mesh.removeprefix(GENERATOR_PREFIX) if mesh.startswith(GENERATOR_PREFIX) else Path(mesh).stem
        obj_id = item.get("id", default_id)
        if not isinstance(obj_id, str) or not _ID.match(obj_id):
            errors.append(f"{where}.id: expected a folder-safe name (letters, digits, _ . -), got {short_repr(obj_id)}")
        elif obj_id in seen:
            errors.append(f"{where}.id: {short_repr(obj_id)} is used by an earlier object; ids must be unique")
        seen.add(str(obj_id))
        size = item.get("size_m")
        if isinstance(size, bool) or not isinstance(size, (int, float)) or not math.isfinite(size) or size <= 0:
            errors.append(f"{where}.size_m: expected the object's height in meters, a number > 0, got {_kind(size)}")
            size = 1.0
        placement = item.get("placement", "ground")
        if placement not in PLACEMENTS:
            errors.append(f"{where}.placement: expected one of {' | '.join(PLACEMENTS)} (ground: it stands on "
                          f"the ground; hanging: a sign, a branch, a lamp), got {_kind(placement)}")
            placement = "ground"
        out.append(ObjectSpec(
            id=str(obj_id), mesh=mesh, size_m=float(size), placement=placement,
            # `growth: {frames: N}` is the parameter growth.frames (as in defaults), for this object
            params={**_params(item.get("params"), f"{where}.params", errors),
                    **_growth(item.get("growth"), where, errors)},
            exclude=_exclude(item.get("exclude"), f"{where}.exclude", errors),
            overrides=_overrides(item.get("overrides"), path, f"{where}.overrides", errors),
            material=_material(item.get("material"), f"{where}.material", errors),
        ))
    return out


def _growth(value: Any, where: str, errors: list[str]) -> dict[str, Any]:
    """An object's ``growth: {frames: N}`` as flat parameters (``growth.frames``)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        errors.append(f"{where}.growth: expected a mapping like {{frames: 24}}, got {_kind(value)}")
        return {}
    return _params({"growth": value}, where, errors)


def _mesh(value: Any, path: Path, where: str, errors: list[str]) -> str:
    if not isinstance(value, str) or not value:
        errors.append(f"{where}: expected a mesh file (relative to the manifest) or generator:NAME, "
                      f"got {_kind(value)}")
        return ""
    if value.startswith(GENERATOR_PREFIX):
        name = value[len(GENERATOR_PREFIX):]
        known = generator_names()
        if known is not None and name not in known:
            hint = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.5)
            tip = (f"did you mean {GENERATOR_PREFIX}{hint[0]}?" if hint
                   else f"expected one of {', '.join(sorted(known))}")
            errors.append(f"{where}: unknown generator {short_repr(name)}; {tip}")
        return value
    file = (path.parent / value).expanduser().resolve()
    if not file.is_file():
        errors.append(f"{where}: mesh file not found: {file}")
    return str(file)


def _vec3(value: Any) -> tuple[float, float, float] | None:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        return None
    if any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in value):
        return None
    return tuple(float(x) for x in value)


def _exclude(value: Any, where: str, errors: list[str]) -> tuple:
    """Boxes as ``{min: [x, y, z], max: [x, y, z]}`` or ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``."""
    if value is None:
        return ()
    if not isinstance(value, list):
        errors.append(f"{where}: expected a list of boxes {{min: [x, y, z], max: [x, y, z]}} in meters, "
                      f"got {_kind(value)}")
        return ()
    boxes = []
    for i, box in enumerate(value):
        if isinstance(box, Mapping):
            _unknown_keys(box, ("min", "max"), f"{where}[{i}]", errors)
            lo, hi = _vec3(box.get("min")), _vec3(box.get("max"))
        elif isinstance(box, list) and len(box) == 2:
            lo, hi = _vec3(box[0]), _vec3(box[1])
        else:
            lo = hi = None
        if lo is None or hi is None:
            errors.append(f"{where}[{i}]: expected a box {{min: [x, y, z], max: [x, y, z]}} in meters, "
                          f"got {short_repr(box)}")
        elif not all(a < b for a, b in zip(lo, hi)):
            errors.append(f"{where}[{i}]: expected min < max on every axis, got min {list(lo)} max {list(hi)}")
        else:
            boxes.append((lo, hi))
    return tuple(boxes)


def _overrides(value: Any, path: Path, where: str, errors: list[str]) -> tuple:
    if value is None:
        return ()
    if not isinstance(value, Mapping):
        errors.append(f"{where}: expected a mapping {{water|drips|trajectories: file}}, got {_kind(value)}")
        return ()
    _unknown_keys(value, tuple(OVERRIDE_STAGES), where, errors)
    out = []
    for stage, suffixes in OVERRIDE_STAGES.items():
        if stage not in value:
            continue
        file = value[stage]
        if not isinstance(file, str) or not file:
            errors.append(f"{where}.{stage}: expected a file path relative to the manifest, got {_kind(file)}")
            continue
        full = (path.parent / file).expanduser().resolve()
        if not full.is_file():
            errors.append(f"{where}.{stage}: file not found: {full}")
        elif full.suffix.lower() not in suffixes:
            errors.append(f"{where}.{stage}: expected a {' or '.join(suffixes)} file (as the job writes it), "
                          f"got {full.name}")
        out.append((stage, str(full)))
    return tuple(out)


def _material(value: Any, where: str, errors: list[str]) -> tuple:
    """The object's material for rendering, checked by the scene module's rules."""
    if value is None:
        return ()
    if too_big(value, 1000):
        errors.append(f"{where}: expected a short mapping (type, color, ...), got one of more than 1,000 items")
        return ()
    from ..scene.config import material_from_dict

    try:
        material_from_dict(value)
    except InputError as exc:
        errors.append(f"{where}: {exc}")
        return ()
    return tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in value.items())


def _sweep(value: Any, errors: list[str]) -> Sweep | None:
    if not isinstance(value, Mapping):
        errors.append(f"sweep: expected a mapping with keys {', '.join(SWEEP_KEYS)}, got {_kind(value)}")
        return None
    _unknown_keys(value, SWEEP_KEYS, "sweep", errors)
    raw_method = value.get("method", "grid")
    try:
        method = SweepMethod(raw_method)
    except ValueError:
        errors.append(f"sweep.method: expected one of grid, zip, random, got {short_repr(raw_method)}")
        return None
    count = value.get("count")
    if method is SweepMethod.RANDOM:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            errors.append(f"sweep.count: a random sweep needs count, an integer >= 1, got {_kind(count)}")
            count = None
    elif count is not None:
        errors.append(f"sweep.count: only a random sweep takes a count; a {method.value} sweep's size "
                      f"comes from its values")
    parameters = value.get("parameters")
    if not isinstance(parameters, Mapping) or not parameters:
        errors.append(f"sweep.parameters: expected a mapping group.param: {{values: [...]}} or {{min, max}}, "
                      f"got {_kind(parameters)}")
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
    return Sweep(method=method, axes=tuple(axes), count=count if method is SweepMethod.RANDOM else None)


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
        errors.append(f"{where}: expected {{values: [...]}} or {{min: a, max: b}}, got {_kind(spec)}")
        return None
    _unknown_keys(spec, AXIS_KEYS, where, errors)
    if "values" in spec or "value" in spec:
        raw = spec.get("values", [spec.get("value")] if "value" in spec else None)
        if not isinstance(raw, list) or not raw:
            errors.append(f"{where}.values: expected a non-empty list of values, got {_kind(raw)}")
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


def manifest_to_dict(manifest: Manifest) -> dict[str, Any]:
    """The manifest as plain data (paths absolute), for ``manifest.resolved.yaml``."""
    def axis(a: Axis) -> dict:
        if a.values:
            return {"values": list(a.values)}
        return {"min": a.low, "max": a.high, "distribution": a.distribution.value}

    out: dict[str, Any] = {"name": manifest.name, "seed": manifest.seed, "render": manifest.render,
                           "source": str(manifest.path)}
    if manifest.sweep is not None:
        sweep: dict[str, Any] = {"method": manifest.sweep.method.value,
                                 "parameters": {a.key: axis(a) for a in manifest.sweep.axes}}
        if manifest.sweep.count is not None:
            sweep["count"] = manifest.sweep.count
        if manifest.sweep.product:
            sweep["crossed_with"] = {a.key: axis(a) for a in manifest.sweep.product}
        out["sweep"] = sweep
    if manifest.fixed:
        out["fixed"] = dict(manifest.fixed)
    out["objects"] = [
        {"id": o.id, "mesh": o.mesh, "size_m": o.size_m, "placement": o.placement,
         "params": P.resolve(manifest.defaults, o.params, manifest.fixed),
         "exclude": [{"min": list(lo), "max": list(hi)} for lo, hi in o.exclude],
         "overrides": dict(o.overrides), "material": {k: list(v) if isinstance(v, tuple) else v
                                                      for k, v in o.material}}
        for o in manifest.objects
    ]
    return out
