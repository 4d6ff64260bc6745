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

The manifest's data model is in `manifest_model`, the YAML reading and size limits in
`manifest_yaml`, the objects in `manifest_objects` and the sweep section in `manifest_sweep`;
this module reads a manifest through them and writes it back as plain data.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .. import params as P
from ..errors import InputError, short_repr
from .manifest_model import Axis, Distribution, Manifest, ObjectSpec, Sweep, SweepMethod
from .manifest_objects import GENERATOR_PREFIX, parse_objects, parse_params
from .manifest_sweep import parse_sweep
from .manifest_yaml import FOLDER_SAFE_RULE, describe, folder_safe, read_yaml, unknown_keys

__all__ = ["Axis", "Distribution", "Manifest", "ObjectSpec", "Sweep", "SweepMethod", "SOURCE_KEY",
           "load_manifest", "manifest_to_dict", "parse_manifest", "source_path", "source_problems"]

TOP_KEYS = ("name", "seed", "render", "defaults", "objects", "sweep")
MAX_ERRORS = 50  # problems listed one by one; the rest are counted


def load_manifest(path: str | Path) -> Manifest:
    """Read and validate the manifest at ``path``.

    Raises
    ------
    InputError
        The file is missing or not YAML, or it has problems: all of them are listed,
        each as ``FILE: key.path: what was expected``.
    """
    path = Path(path).expanduser().resolve()
    return parse_manifest(read_yaml(path), path)


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
        errors.append(f"(top): expected a mapping with keys {', '.join(TOP_KEYS)}, got {describe(data)}")
        return None
    unknown_keys(data, TOP_KEYS, "", errors)
    name = data.get("name", path.stem)
    if not folder_safe(name):
        errors.append(f"name: expected a folder-safe name ({FOLDER_SAFE_RULE}), got {short_repr(name)}")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        errors.append(f"seed: expected an integer >= 0, got {short_repr(seed)}")
    render = _render(data.get("render"), path, errors)
    defaults = parse_params(data.get("defaults"), "defaults", errors)
    objects = parse_objects(data.get("objects"), path, errors)
    sweep = parse_sweep(data.get("sweep"), errors) if data.get("sweep") is not None else None
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
    """Where a job looks for its ``water.source`` mesh (as `icefarm.job.pipeline` does):
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


def _render(value: Any, path: Path, errors: list[str]) -> str | None:
    """A render config name (render_configs/NAME.yaml) or a path; None/false means no render."""
    if value is None or value is False or value == "none":
        return None
    if not isinstance(value, str) or not value:
        errors.append(f"render: expected a render config name (e.g. preview) or a path, got {describe(value)}")
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
         "params": P.resolve(manifest.defaults, o.params, manifest.fixed).as_dict(),
         "exclude": [{"min": list(lo), "max": list(hi)} for lo, hi in o.exclude],
         "overrides": dict(o.overrides), "material": o.material.to_dict() if o.material else {}}
        for o in manifest.objects
    ]
    return out
