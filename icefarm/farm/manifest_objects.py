"""The ``objects`` of a manifest (mesh, size, placement, exclude boxes, stage overrides,
material, growth) and the parameter mappings they and the ``defaults`` hold.

Each function appends every problem it finds to ``errors`` (as ``key.path: what was expected``)
and returns what it could validate, so that the manifest's problems are all reported at once.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .. import params as P
from ..errors import InputError, short_repr
from ..placement import PLACEMENTS
from .manifest_model import ObjectSpec
from .manifest_yaml import FOLDER_SAFE_RULE, MAX_VALUE_ITEMS, describe, folder_safe, key_path, too_big, unknown_keys

GENERATOR_PREFIX = "generator:"
OVERRIDE_STAGES = {"water": (".ply",), "drips": (".json",), "trajectories": (".json",)}
OBJECT_KEYS = ("id", "mesh", "size_m", "placement", "params", "exclude", "overrides", "material", "growth")


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


def parse_params(value: Any, where: str, errors: list[str]) -> dict[str, Any]:
    """Parameters as nested ``{group: {name: v}}`` or flat ``{"group.name": v}`` to validated flat keys."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        errors.append(f"{where}: expected a mapping of parameters (group.name: value), got {describe(value)}")
        return {}
    flat: dict[str, Any] = {}
    for key, v in value.items():
        if isinstance(v, Mapping):
            if key not in P.GROUPS:
                hint = difflib.get_close_matches(str(key), P.GROUPS, n=1, cutoff=0.5)
                tip = f"did you mean {hint[0]!r}?" if hint else f"expected one of {', '.join(P.GROUPS)}"
                errors.append(f"{key_path(where, key)}: unknown parameter group; {tip}")
                continue
            items = [(f"{key}.{name}", x) for name, x in v.items()]
        else:
            items = [(str(key), v)]
        for full, x in items:
            if too_big(x):
                errors.append(f"{key_path(where, full)}: a value of more than {MAX_VALUE_ITEMS:,} items "
                              "(nested YAML aliases?): expected a number, a word or a short list")
                continue
            try:
                param = P.lookup(full)
                flat[param.key] = param.validate(x)
            except InputError as exc:
                errors.append(f"{key_path(where, full)}: {exc}")
    return flat


def parse_objects(value: Any, path: Path, errors: list[str]) -> list[ObjectSpec]:
    """The ``objects`` list; mesh and override paths are taken from ``path``'s folder."""
    if not isinstance(value, list) or not value:
        errors.append(f"objects: expected a non-empty list of objects (id, mesh, size_m, ...), got {describe(value)}")
        return []
    out: list[ObjectSpec] = []
    seen: set[str] = set()
    for i, item in enumerate(value):
        where = f"objects[{i}]"
        if not isinstance(item, Mapping):
            errors.append(f"{where}: expected a mapping with keys id, mesh, size_m, ..., got {describe(item)}")
            continue
        unknown_keys(item, OBJECT_KEYS, where, errors)
        mesh = _mesh(item.get("mesh"), path, f"{where}.mesh", errors)
        default_id = mesh.removeprefix(GENERATOR_PREFIX) if mesh.startswith(GENERATOR_PREFIX) else Path(mesh).stem
        obj_id = item.get("id", default_id)
        if not folder_safe(obj_id):
            errors.append(f"{where}.id: expected a folder-safe name ({FOLDER_SAFE_RULE}), got {short_repr(obj_id)}")
        elif obj_id in seen:
            errors.append(f"{where}.id: {short_repr(obj_id)} is used by an earlier object; ids must be unique")
        seen.add(str(obj_id))
        size = item.get("size_m")
        if size is None and mesh:  # USD, glTF and the real-size generators carry their size
            why = _missing_size(mesh)
            if why:
                errors.append(f"{where}.size_m: {why}: give the object's height in meters")
        elif isinstance(size, bool) or not isinstance(size, (int, float)) or not math.isfinite(size) or size <= 0:
            errors.append(f"{where}.size_m: expected the object's height in meters, a number > 0, got {describe(size)}")
            size = 1.0
        placement = item.get("placement", "ground")
        if placement not in PLACEMENTS:
            errors.append(f"{where}.placement: expected one of {' | '.join(PLACEMENTS)} (ground: it stands on "
                          f"the ground; hanging: a sign, a branch, a lamp), got {describe(placement)}")
            placement = "ground"
        out.append(ObjectSpec(
            id=str(obj_id), mesh=mesh, size_m=None if size is None else float(size), placement=placement,
            # `growth: {frames: N}` is the parameter growth.frames (as in defaults), for this object;
            # a USD or glTF file's up axis is its water.gravity unless its params set one
            params=_asset_gravity(mesh, {**parse_params(item.get("params"), f"{where}.params", errors),
                                         **_growth(item.get("growth"), where, errors)}, where, errors),
            exclude=_exclude(item.get("exclude"), f"{where}.exclude", errors),
            overrides=_overrides(item.get("overrides"), path, f"{where}.overrides", errors),
            material=_material(item.get("material"), f"{where}.material", errors),
        ))
    return out


def _missing_size(mesh: str) -> str | None:
    """Why ``mesh`` needs a ``size_m`` (`icefarm.asset_io.missing_size`); None for a missing
    file or an unknown generator, which are reported on their own."""
    from ..asset_io import missing_size

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        return None
    try:
        return missing_size(mesh)
    except InputError:
        return None


def _asset_gravity(mesh: str, params: dict[str, Any], where: str, errors: list[str]) -> dict[str, Any]:
    """An object's params with ``water.gravity`` from its file's up axis when they set none:
    the asset knows its up axis better than the manifest's defaults, which may be there for
    other objects; a sweep or ``--set`` still wins."""
    from ..asset_io import with_asset_gravity

    if not mesh or not Path(mesh).is_file():
        return params
    try:
        return with_asset_gravity(mesh, params)
    except InputError as exc:
        errors.append(f"{where}.mesh: {exc}")
        return params


def _growth(value: Any, where: str, errors: list[str]) -> dict[str, Any]:
    """An object's ``growth: {frames: N}`` as flat parameters (``growth.frames``)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        errors.append(f"{where}.growth: expected a mapping like {{frames: 24}}, got {describe(value)}")
        return {}
    return parse_params({"growth": value}, where, errors)


def _mesh(value: Any, path: Path, where: str, errors: list[str]) -> str:
    if not isinstance(value, str) or not value:
        errors.append(f"{where}: expected a mesh file (relative to the manifest) or generator:NAME, "
                      f"got {describe(value)}")
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
    """`Box` es, given as ``{min: [x, y, z], max: [x, y, z]}`` or ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``."""
    from ..job.pipeline import Box

    if value is None:
        return ()
    if not isinstance(value, list):
        errors.append(f"{where}: expected a list of boxes {{min: [x, y, z], max: [x, y, z]}} in meters, "
                      f"got {describe(value)}")
        return ()
    boxes = []
    for i, box in enumerate(value):
        if isinstance(box, Mapping):
            unknown_keys(box, ("min", "max"), f"{where}[{i}]", errors)
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
            boxes.append(Box(lo, hi))
    return tuple(boxes)


def _overrides(value: Any, path: Path, where: str, errors: list[str]) -> tuple:
    if value is None:
        return ()
    if not isinstance(value, Mapping):
        errors.append(f"{where}: expected a mapping {{water|drips|trajectories: file}}, got {describe(value)}")
        return ()
    unknown_keys(value, tuple(OVERRIDE_STAGES), where, errors)
    out = []
    for stage, suffixes in OVERRIDE_STAGES.items():
        if stage not in value:
            continue
        file = value[stage]
        if not isinstance(file, str) or not file:
            errors.append(f"{where}.{stage}: expected a file path relative to the manifest, got {describe(file)}")
            continue
        full = (path.parent / file).expanduser().resolve()
        if not full.is_file():
            errors.append(f"{where}.{stage}: file not found: {full}")
        elif full.suffix.lower() not in suffixes:
            errors.append(f"{where}.{stage}: expected a {' or '.join(suffixes)} file (as the job writes it), "
                          f"got {full.name}")
        out.append((stage, str(full)))
    return tuple(out)


def _material(value: Any, where: str, errors: list[str]):
    """The object's `Material` for rendering, checked by the scene module's rules; None for the default."""
    if value is None:
        return None
    if too_big(value, 1000):
        errors.append(f"{where}: expected a short mapping (type, color, ...), got one of more than 1,000 items")
        return None
    from ..scene.material import material_from_dict

    try:
        return material_from_dict(value)
    except InputError as exc:
        errors.append(f"{where}: {exc}")
        return None

