"""Render configurations: ``render_configs/*.yaml`` read, validated and frozen.

A render config says how a job is rendered (renderer, variant, resolution, samples,
views) and how the ice and its surroundings look (ior, roughness, absorption, cloudiness,
sky, sun, ground).
Keys are checked like parameters: an unknown key is refused with the nearest valid one,
a wrong value with the key, the value and what was expected (the value checks are
`config_checks`; the object's material, which a manifest states, is `material`).
"""

from __future__ import annotations

import difflib
import importlib.resources
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from ..errors import InputError
from ..yaml_io import load_yaml
from .config_checks import (
    MAX_ABSORPTION,
    check_absorption,
    check_resolution,
    check_sky,
    choice_check,
    number_check,
    refusal,
    triple_check,
)

RENDERERS = ("mitsuba", "povray", "both")
VARIANTS = ("auto", "scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
GROUNDS = ("checker", "plain", "none")
DENOISERS = ("none", "oidn")  # oidn: Intel Open Image Denoise, with albedo and normal features
# Shipped inside the package (package data), so a plain `pip install` renders; the repo's
# top-level render_configs/ is a link to it, where users look.
CONFIG_DIR = Path(str(importlib.resources.files("icefarm") / "render_configs"))

FRAMES = ("all", "ice")
# Named views: (azimuth, elevation) in degrees around "up" (minus gravity). Azimuth 0
# looks at the object's front, 90 at its right side; negative elevation looks up at it.
NAMED_VIEWS: dict[str, tuple[float, float]] = {
    "three_quarter": (35.0, -8.0),  # slightly below: icicles hang, the sky shows through them
    "front": (0.0, 5.0),
    "side": (90.0, 5.0),
    "back": (200.0, 5.0),
    "above": (35.0, 35.0),
    "below": (35.0, -25.0),
    "ice": (35.0, -8.0),  # the three-quarter view's camera, zoomed on the densest icicles
}
# Named views that frame the ice rather than everything.
NAMED_FRAMES: dict[str, str] = {"ice": "ice"}


@dataclass(frozen=True)
class View:
    """One camera direction: azimuth and elevation in degrees (the camera sits there).

    ``frame`` is what the view shows: ``all`` (object and ice, the whole scene) or ``ice``
    (a zoom from the same camera position onto the densest cluster of icicles, close
    enough that icicles are several pixels wide; see `camera.ice_focus`).
    """

    name: str
    azimuth: float
    elevation: float
    frame: str = "all"


# Ice absorption, per meter (R, G, B): white light through 25 cm of ice comes out
# (0.45, 0.78, 0.84), through a 2 cm icicle (0.94, 0.98, 0.986). Real ice absorbs about
# 0.02 /m in the blue and some 0.5 /m in the red: this exaggerates a real effect (six times
# in the red) so that a fat icicle reads as ice and not as a glass rod, while a thin one
# stays clear; at 2.5 times this, a meltwater eave's 5 cm icicles read as teal resin.
ABSORPTION_PER_M = (3.2, 1.0, 0.7)
# Scattering (per meter) of ice whose water carried the most impurities (surface.impurity
# = 1): bubbles and brine inclusions cloud an impure icicle's core. Bubbly ice measures
# about 1-8 /m (a tap-water icicle's default impurity 0.7: 5.6 /m); at 15 /m fat icicles
# read milky. A job's scattering is this times its impurity (0: clear).
SCATTERING_PER_M = 8.0
# Impure icicles hold milky inclusions under their ripple crests (Ladan & Morris, Phys. Rev.
# E 106, 2022): seen through the ice the ripples are a shimmer of bands, not grooves. Under a
# full crest of ice from the most impure water (surface.impurity = 1) this share of the
# light goes through a frosted surface instead of a clear one (`IceLook.shimmer`). At 1 the
# bands read as screw threads down a dense fringe; real impure ice shows them faintly.
SHIMMER = 0.4


@dataclass(frozen=True)
class IceLook:
    """The ice's look: the one record of it, for the render configs, the scene spec and the exports.

    A render config's ``ice`` gives ``scattering`` and ``shimmer`` at ``surface.impurity`` 1;
    a `SceneSpec`'s ice is a job's, with its impurity applied (`ice_at_impurity`) and its
    shimmer 0 where the ice mesh has no ripple crests.

    Attributes
    ----------
    ior : float
        Index of refraction (1.31, water ice).
    roughness : float
        GGX roughness (alpha) of the surface (0: smooth); formats with a perceptual
        roughness take its square root.
    tint : (3,) float
        Transmittance per surface crossing (1, 1, 1: none); the colour of thick ice comes
        from ``absorption``, which depends on the distance travelled.
    absorption : (3,) float
        Absorption coefficients per meter (R, G, B) inside the ice (Beer-Lambert).
    scattering : float
        Scattering coefficient per meter: the milky core of ice grown from impure water.
    shimmer : float
        Share of the light frosted under a full ripple crest (0: clear ripples): milky
        bands along rippled icicles.
    """

    ior: float = 1.31
    roughness: float = 0.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    absorption: tuple[float, float, float] = ABSORPTION_PER_M
    scattering: float = SCATTERING_PER_M
    shimmer: float = SHIMMER


@dataclass(frozen=True)
class IceMedium:
    """What fills the ice, per meter: absorption (R, G, B) and a grey scattering coefficient.

    Scattering is isotropic (Mitsuba's default phase function for a ``homogeneous`` medium).
    """

    absorption: tuple[float, float, float]
    scattering: float

    @property
    def extinction(self) -> tuple[float, float, float]:
        return tuple(a + self.scattering for a in self.absorption)

    @property
    def albedo(self) -> tuple[float, float, float]:
        return tuple(self.scattering / t if t > 0 else 0.0 for t in self.extinction)


def ice_at_impurity(look: IceLook, impurity: float) -> IceLook:
    """The ice of a job with ``impurity`` (``surface.impurity``, [0, 1]): ``look``'s scattering
    and shimmer, which a render config gives at impurity 1, scaled by it (0: clear ice).

    Raises
    ------
    ValueError
        ``impurity`` outside [0, 1].
    """
    impurity = float(impurity)
    if not 0.0 <= impurity <= 1.0:
        raise ValueError(f"impurity must be in [0, 1], got {impurity}")
    return replace(look, tint=tuple(look.tint), absorption=tuple(float(a) for a in look.absorption),
                   scattering=float(look.scattering) * impurity, shimmer=look.shimmer * impurity)


def ice_medium(ice: IceLook) -> IceMedium | None:
    """What fills a job's ice (`ice_at_impurity`), None when it neither absorbs nor scatters."""
    medium = IceMedium(tuple(float(a) for a in ice.absorption), float(ice.scattering))
    return medium if max(medium.extinction) > 0 else None


# Ground albedos (linear): dark enough that clear icicles read against it by their bright
# refracted sky and highlights, as against wet asphalt or dark earth.
GROUND_CHECKER = ((0.085, 0.08, 0.075), (0.15, 0.14, 0.13))
GROUND_PLAIN = (0.11, 0.105, 0.1)


@dataclass(frozen=True)
class Environment:
    """Light and surroundings.

    ``sky`` is ``"procedural"`` (a generated sky with horizon and bright patches) or the
    path of an equirectangular EXR/HDR image. Strengths are linear scales; ``exposure``
    (stops) scales every light. The sun direction is given in degrees like a view.
    """

    sky: str = "procedural"
    sky_strength: float = 1.0
    sun_strength: float = 3.0
    sun_azimuth: float = 120.0
    sun_elevation: float = 45.0
    ground: str = "checker"
    exposure: float = 0.0


@dataclass(frozen=True)
class RenderConfig:
    """How one job is rendered; see ``render_configs/*.yaml``.

    Attributes
    ----------
    renderer : {"mitsuba", "povray", "both"}
    variant : {"auto", "scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"}
        Mitsuba variant; ``auto`` picks the fastest that works on this machine.
    resolution : (width, height) pixels
    spp : int
        Samples per pixel (Mitsuba).
    max_depth : int
        Longest light path; ice needs several bounces.
    denoise : {"none", "oidn"}
        ``oidn`` denoises each view with Intel Open Image Denoise, guided by the albedo
        and normal of what each pixel shows (through the ice, what lies behind it):
        fewer samples give the same image. The EXR stays linear and says so in its
        ``icefarm:denoised`` attribute.
    views : tuple of View
        The first is the main view (``render.png``); others give ``render_view<i>.png``.
    fov : float
        Vertical field of view, degrees.
    ice : IceLook
    environment : Environment
    name : str
        The config's name (file stem), for labels only.
    """

    renderer: str = "mitsuba"
    variant: str = "auto"
    resolution: tuple[int, int] = (320, 240)
    spp: int = 32
    max_depth: int = 12
    denoise: str = "none"
    views: tuple[View, ...] = (View("three_quarter", *NAMED_VIEWS["three_quarter"]),)
    fov: float = 30.0
    ice: IceLook = field(default_factory=IceLook)
    environment: Environment = field(default_factory=Environment)
    name: str = "custom"

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    @property
    def uses_mitsuba(self) -> bool:
        return self.renderer in ("mitsuba", "both")

    @property
    def uses_povray(self) -> bool:
        return self.renderer in ("povray", "both")


def parse_view(key: str, value: Any) -> View:
    """A view from a name (``three_quarter``, ``ice``), ``[azimuth, elevation]`` or a mapping.

    A mapping may add ``frame: ice`` to zoom on the ice (``frame: all``, the default,
    frames everything).
    """
    expected = ("a view name (" + " | ".join(NAMED_VIEWS) + "), [azimuth, elevation] in degrees"
                " with elevation in [-89, 89], or {azimuth: .., elevation: .., frame: all | ice}")
    if isinstance(value, View):
        return value
    if isinstance(value, str):
        if value not in NAMED_VIEWS:
            hint = difflib.get_close_matches(value, list(NAMED_VIEWS), n=1, cutoff=0.5)
            raise refusal(key, value, expected + (f"; did you mean {hint[0]!r}?" if hint else ""))
        return View(value, *NAMED_VIEWS[value], frame=NAMED_FRAMES.get(value, "all"))
    frame = "all"
    if isinstance(value, Mapping):
        unknown = set(value) - {"azimuth", "elevation", "name", "frame"}
        if unknown or not {"azimuth", "elevation"} <= set(value):
            raise refusal(key, value, expected)
        az, el, name = value["azimuth"], value["elevation"], value.get("name")
        frame = value.get("frame", "all")
        if frame not in FRAMES:
            raise refusal(f"{key}.frame", frame, "one of " + " | ".join(FRAMES))
    elif isinstance(value, Sequence) and not isinstance(value, (str, bytes)) and len(value) == 2:
        (az, el), name = value, None
    else:
        raise refusal(key, value, expected)
    for v in (az, el):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise refusal(key, value, expected)
    if not -89.0 <= el <= 89.0:
        raise refusal(key, value, expected)
    name = str(name) if name else f"az{az:g}_el{el:g}" + ("_ice" if frame == "ice" else "")
    return View(name, float(az), float(el), frame)


def _views(key, value):
    if isinstance(value, (str, Mapping)):
        value = [value]
    if not isinstance(value, Sequence) or not value or len(value) > 16:
        raise refusal(key, value, "a list of 1 to 16 views")
    return tuple(parse_view(f"{key}[{i}]", v) for i, v in enumerate(value))


_ICE: dict[str, Callable] = {
    "ior": number_check(1.0, 3.0),
    "roughness": number_check(0.0, 1.0),
    "tint": triple_check(0.0, 1.0),
    "absorption": check_absorption,
    "scattering": number_check(0.0, MAX_ABSORPTION),
    "shimmer": number_check(0.0, 1.0),
}
_ENVIRONMENT: dict[str, Callable] = {
    "sky": check_sky,
    "sky_strength": number_check(0.0, 1000.0),
    "sun_strength": number_check(0.0, 1000.0),
    "sun_azimuth": number_check(-360.0, 360.0),
    "sun_elevation": number_check(-90.0, 90.0),
    "ground": choice_check(GROUNDS),
    "exposure": number_check(-20.0, 20.0),
}
_TOP: dict[str, Callable] = {
    "renderer": choice_check(RENDERERS),
    "variant": choice_check(VARIANTS),
    "resolution": check_resolution,
    "spp": number_check(1, 1 << 16, integer=True),
    "max_depth": number_check(1, 1000, integer=True),
    "denoise": choice_check(DENOISERS),
    "views": _views,
    "fov": number_check(1.0, 170.0),
}
_GROUPS = {"ice": _ICE, "environment": _ENVIRONMENT}
ALL_KEYS = tuple(_TOP) + tuple(f"{g}.{k}" for g, checks in _GROUPS.items() for k in checks)


def _unknown(key: str) -> InputError:
    hint = difflib.get_close_matches(key, ALL_KEYS, n=1, cutoff=0.5)
    if not hint:
        hint = [k for k in ALL_KEYS if k.split(".")[-1] == key.split(".")[-1]][:1]
    tip = f"; did you mean {hint[0]!r}?" if hint else "; valid keys: " + ", ".join(ALL_KEYS)
    return InputError(f"render config: unknown key {key!r}{tip}")


def _flatten(values: Mapping[str, Any]) -> dict[str, Any]:
    """Nested ``{ice: {ior: ..}}`` and dotted ``{"ice.ior": ..}`` keys to dotted keys."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        key = str(key)
        if key in _GROUPS:
            if not isinstance(value, Mapping):
                raise refusal(key, value, f"a mapping of {', '.join(_GROUPS[key])}")
            for sub, v in value.items():
                flat[f"{key}.{sub}"] = v
        else:
            flat[key] = value
    return flat


def render_config_from_dict(values: Mapping[str, Any] | None, base: RenderConfig | None = None,
                            name: str | None = None, root: Path | None = None) -> RenderConfig:
    """Validate ``values`` over ``base`` (the built-in defaults when None).

    Parameters
    ----------
    values : mapping
        Nested or dotted keys (``{"ice": {"roughness": 0.1}}`` or ``{"ice.roughness": 0.1}``).
    base : RenderConfig, optional
    name : str, optional
        The name the result carries.
    root : Path, optional
        Folder that relative paths (``environment.sky``) are relative to.

    Raises
    ------
    InputError
        Unknown key (with the nearest valid one), or a value of the wrong type or range.
    """
    base = base or RenderConfig()
    if values is None:
        values = {}
    if not isinstance(values, Mapping):
        raise InputError(f"render config: expected a mapping of keys, got {type(values).__name__}")
    top: dict[str, Any] = {}
    groups: dict[str, dict[str, Any]] = {g: {} for g in _GROUPS}
    for key, value in _flatten(values).items():
        group, _, sub = key.partition(".")
        if key in _TOP:
            top[key] = _TOP[key](key, value)
        elif group in _GROUPS and sub in _GROUPS[group]:
            if key == "environment.sky" and root is not None and isinstance(value, str) \
                    and value != "procedural" and not Path(value).expanduser().is_absolute():
                value = str(root / value)
            groups[group][sub] = _GROUPS[group][sub](key, value)
        else:
            raise _unknown(key)
    return replace(base, **top, ice=replace(base.ice, **groups["ice"]),
                   environment=replace(base.environment, **groups["environment"]),
                   name=name or base.name)


def config_names() -> list[str]:
    """Names of the configs in ``render_configs/`` (``preview``, ``lookdev``, ``final``)."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")) if CONFIG_DIR.is_dir() else []


def load_render_config(name_or_path: str | os.PathLike[str],
                       overrides: Mapping[str, Any] | None = None) -> RenderConfig:
    """Read a render config by name (``"preview"``) or YAML path, with optional overrides.

    Parameters
    ----------
    name_or_path : str or Path
        A name from ``render_configs/`` or the path of a YAML file.
    overrides : mapping, optional
        Keys applied over the file, validated the same way (for sweeps over look keys).

    Raises
    ------
    InputError
        Missing file, unreadable YAML, unknown key or bad value.
    """
    path = Path(name_or_path).expanduser()
    if not path.is_file():
        named = CONFIG_DIR / f"{name_or_path}.yaml"
        if str(name_or_path) in config_names():
            path = named
        else:
            names = config_names()
            hint = difflib.get_close_matches(str(name_or_path), names, n=1, cutoff=0.5)
            tip = f"; did you mean {hint[0]!r}?" if hint else ""
            raise InputError(f"render config {str(name_or_path)!r} is neither a file nor one of "
                             f"{', '.join(names) or '(none found)'}{tip}")
    try:
        data = load_yaml(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read render config {path}: {exc}") from None
    try:
        config = render_config_from_dict(data, name=path.stem, root=path.parent)
        return render_config_from_dict(overrides, base=config, root=Path.cwd())
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def render_config_to_dict(config: RenderConfig) -> dict[str, Any]:
    """Plain YAML-ready dict of ``config`` (no name): round-trips through `render_config_from_dict`."""
    out = asdict(config)
    out.pop("name")
    out["resolution"] = list(config.resolution)
    out["views"] = [v.name if NAMED_VIEWS.get(v.name) == (v.azimuth, v.elevation)
                    and NAMED_FRAMES.get(v.name, "all") == v.frame
                    else {"name": v.name, "azimuth": v.azimuth, "elevation": v.elevation,
                          **({"frame": v.frame} if v.frame != "all" else {})}
                    for v in config.views]
    out["ice"]["tint"] = list(config.ice.tint)
    out["ice"]["absorption"] = list(config.ice.absorption)
    return out
