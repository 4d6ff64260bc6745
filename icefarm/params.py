"""Parameters resolved and typed: ``group.name`` keys (``trajectories.curve_angle``) looked
up in the registry (`icefarm.param_table`), validated once by `resolve` into a frozen
`Params` of one frozen dataclass per group (`icefarm.param_groups`;
``params.surface.tip_radius``). `Params.as_dict` is the plain nested form that round-trips
through YAML and hashes stably.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from .errors import InputError
from .geometry import world_frame
from .param_groups import (
    DripsParams,
    GlazeParams,
    GroundIceParams,
    GrowthParams,
    ProxyParams,
    StormParams,
    SurfaceParams,
    TrajectoriesParams,
    WaterParams,
)
from .param_table import DEFAULT_WIND_MPS, PARAMS, Kind, Param
from .yaml_io import load_yaml

__all__ = ["GROUPS", "PARAMS", "DripsParams", "GlazeParams", "GroundIceParams", "GrowthParams", "Kind", "Param",
           "Params", "ProxyParams", "StormParams", "SurfaceParams", "TrajectoriesParams", "WaterParams", "defaults",
           "flatten", "group_type", "lookup", "idle_keys", "param_index", "parse_assignment", "parse_assignments",
           "parse_value", "resolve", "table", "typed"]


GROUPS: tuple[str, ...] = ("storm", "water", "drips", "trajectories", "surface", "glaze", "ground_ice", "growth",
                          "proxy")


def param_index() -> dict[str, Param]:
    """Map ``group.name`` to its `Param`."""
    return {p.key: p for p in PARAMS}


def lookup(key: str) -> Param:
    """The `Param` named ``key``; an unknown key raises `InputError` with the nearest valid one."""
    index = param_index()
    if key in index:
        return index[key]
    hint = difflib.get_close_matches(key, list(index), n=1, cutoff=0.5)
    if not hint and "." not in key:
        hint = [k for k in index if k.endswith("." + key)][:1]
    tip = f"; did you mean {hint[0]}?" if hint else "; `icefarm params` lists them"
    raise InputError(f"unknown parameter {key!r}{tip}")


def defaults() -> dict[str, dict[str, Any]]:
    """All defaults as ``{group: {name: value}}`` (fresh copies)."""
    out: dict[str, dict[str, Any]] = {g: {} for g in GROUPS}
    for p in PARAMS:
        out[p.group][p.name] = list(p.default) if isinstance(p.default, list) else p.default
    return out


def flatten(values: Mapping[str, Any]) -> dict[str, Any]:
    """``{group: {name: v}}`` or already flat ``{"group.name": v}`` to flat keys."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, Mapping):
            for name, v in value.items():
                flat[f"{key}.{name}"] = v
        else:
            flat[key] = value
    return flat


def resolve(*layers: Mapping[str, Any] | Params | None) -> Params:
    """Defaults overlaid with each layer in turn, every value validated, once.

    Parameters
    ----------
    *layers
        Mappings, nested ``{group: {name: value}}`` or flat ``{"group.name": value}``, or
        `Params`; later layers win. ``None`` layers are skipped.

    Returns
    -------
    Params
        Every parameter, typed; ``water.gravity`` a unit vector.

    Raises
    ------
    InputError
        For an unknown key (with the nearest valid one) or a value outside its domain.
    """
    out = defaults()
    wind_given = False
    for layer in layers:
        flat = flatten(layer.as_dict() if isinstance(layer, Params) else layer or {})
        wind_given |= "storm.wind" in flat
        for key, value in flat.items():
            param = lookup(key)
            out[param.group][param.name] = param.validate(value)
        # Legacy glaze.balls (ngi) as the glaze's switch: 0 is no glaze; a positive count turns
        # the glaze on. A glaze.mode in the same layer wins.
        if "glaze.balls" in flat and "glaze.mode" not in flat:
            if out["glaze"]["balls"] == 0:
                out["glaze"]["mode"] = "none"
            else:
                import warnings

                warnings.warn(f"glaze.balls = {out['glaze']['balls']} is a legacy key and only turns the glaze on "
                              "(0 turns it off): the default glaze is a continuous coat; for balls set "
                              "glaze.mode = metaballs and glaze.density (per square meter)", FutureWarning,
                              stacklevel=2)
                if out["glaze"]["mode"] == "none":
                    out["glaze"]["mode"] = "coat"
    for p in PARAMS:  # the defaults go through the same checks and coercions
        out[p.group][p.name] = p.validate(out[p.group][p.name])
    del out["glaze"]["balls"]  # stood for glaze.mode (above)
    g = np.asarray(out["water"]["gravity"], dtype=np.float64)
    out["water"]["gravity"] = (g / np.linalg.norm(g)).tolist()  # normalised here, once
    if not wind_given:  # the default breeze blows from the asset's front, whichever way is up
        out["storm"]["wind"] = ((-DEFAULT_WIND_MPS * world_frame(g)[2]).round(12) + 0.0).tolist()
    return Params(**{group: _build(group, values) for group, values in out.items()})


_PYTHON_TYPES: dict[Kind, Any] = {Kind.INT: int, Kind.FLOAT: float, Kind.CHOICE: str,
                                  Kind.VECTOR: tuple[float, float, float], Kind.TEXT: str}
_RETIRED = {"glaze.balls"}  # stands for glaze.mode in `resolve`, absent from its result
_GROUP_TYPES: dict[str, type[Any]] = {
    "storm": StormParams, "water": WaterParams, "drips": DripsParams, "trajectories": TrajectoriesParams,
    "surface": SurfaceParams, "glaze": GlazeParams, "ground_ice": GroundIceParams, "growth": GrowthParams,
    "proxy": ProxyParams,
}


def group_type(group: str) -> type[Any]:
    """The frozen dataclass of ``group``'s parameters (`icefarm.param_groups`).

    ``group_type("surface")`` is `SurfaceParams`, one typed field per parameter of the
    registry (vectors are tuples): what stage 4 reads as ``surface.tip_radius``. Build
    instances with `typed`, which validates.
    """
    if group not in _GROUP_TYPES:
        raise ValueError(f"no parameter group {group!r}; one of {', '.join(GROUPS)}")
    return _GROUP_TYPES[group]


def _build(group: str, values: Mapping[str, Any]) -> Any:
    """``group``'s dataclass from values already validated (vectors become tuples)."""
    return group_type(group)(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


@dataclass(frozen=True)
class Params:
    """Every parameter of a job, validated once by `resolve`: one frozen group per stage.

    ``params.surface.tip_radius``; `as_dict` is the plain nested form (YAML, hashing);
    `updated` lays more values over it (validated again).
    """

    storm: StormParams
    water: WaterParams
    drips: DripsParams
    trajectories: TrajectoriesParams
    surface: SurfaceParams
    glaze: GlazeParams
    ground_ice: GroundIceParams
    growth: GrowthParams
    proxy: ProxyParams

    @property
    def gravity(self) -> np.ndarray:
        """``(3,)`` unit vector: the direction water falls."""
        return np.asarray(self.water.gravity, dtype=np.float64)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """``{group: {name: value}}``, vectors as lists: what ``params.yaml`` holds."""
        return {group: {k: list(v) if isinstance(v, tuple) else v
                        for k, v in dataclasses.asdict(getattr(self, group)).items()} for group in GROUPS}

    def updated(self, *layers: Mapping[str, Any] | None) -> Params:
        """These values with ``layers`` laid over them (`resolve`)."""
        return resolve(self, *layers)


def typed(group: str, values: Any) -> Any:
    """One group's values as its frozen dataclass (`group_type`), validated once, here.

    Parameters
    ----------
    group : str
        ``surface``, ``glaze``, ``proxy``, ...
    values : mapping or group_type(group)
        ``resolve()[group]``, or a partial mapping laid over the defaults; an instance of
        the group's dataclass passes through unchecked (it was checked when built).

    Raises
    ------
    InputError
        An unknown name or a value outside its domain.
    """
    cls = group_type(group)
    if isinstance(values, cls):
        return values
    if not isinstance(values, Mapping):
        raise TypeError(f"{group} parameters must be a mapping or {cls.__name__}, not {type(values).__name__}")
    fields = {f.name for f in dataclasses.fields(cls)}
    for name in values:
        if name not in fields:
            lookup(f"{group}.{name}")  # the nearest valid name
            raise InputError(f"{group}.{name} is a legacy parameter: resolve the parameters first "
                             "(`icefarm.params.resolve`)")
    out = {}
    for p in PARAMS:
        if p.group == group and p.name in fields:
            value = p.validate(values[p.name] if p.name in values else p.default)
            out[p.name] = tuple(value) if isinstance(value, list) else value
    return cls(**out)


def parse_value(text: str) -> Any:
    """A command-line value: YAML scalars (``2``, ``0.5``, ``tubes``, ``[0,-1,0]``)."""
    try:
        return load_yaml(text)
    except yaml.YAMLError:
        return text


def parse_assignment(text: str) -> tuple[str, Any]:
    """``"group.name=value"`` to ``(key, value)``; the key is checked, the value parsed."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"expected group.param=value, got {text!r}")
    return lookup(key.strip()).key, parse_value(raw.strip())


def parse_assignments(values: Iterable[str]) -> dict[str, Any]:
    """``--set GROUP.PARAM=VALUE`` pairs as ``{"group.param": value}``."""
    return dict(parse_assignment(v) for v in values)


def table() -> list[dict[str, Any]]:
    """One row per parameter: group, name, symbol, unit, domain, default, the storm mode that
    reads it (``physical``, ``relative`` or ``both``), doc."""
    return [
        {"group": p.group, "name": p.name, "symbol": p.symbol, "unit": p.unit,
         "domain": p.domain, "default": p.default, "mode": p.mode or "both", "doc": p.doc}
        for p in PARAMS
    ]


def idle_keys(keys: Iterable[str], mode: str) -> list[str]:
    """One line per key of ``keys`` that a job under storm ``mode`` does not read.

    ``idle_keys(["drips.count"], "physical")`` says that the physical storm places its icicles
    along the rims at ``drips.spacing`` instead. Unknown keys are left to `lookup`.
    """
    index = param_index()
    lines = []
    for key in dict.fromkeys(keys):
        p = index.get(key)
        if p is not None and p.mode and p.mode != mode:
            lines.append(f"{key} does nothing under storm.mode {mode}, which uses {p.instead}; "
                         f"only storm.mode={p.mode} reads it")
    return lines
