"""The object's material: ``{type: diffuse|plastic|metal, color, roughness, metal}``.

A manifest states it per object; `material_from_dict` validates it once into a frozen
`Material`, missing keys taking `DEFAULT_MATERIAL`'s values; the scene writers read that.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Callable, Mapping
from typing import Any

from ..errors import InputError
from .config_checks import choice_check, number_check, triple_check

MATERIAL_TYPES = ("diffuse", "plastic", "metal")
METALS = ("Al", "Ag", "Au", "Cu", "Cr")
_MATERIAL: dict[str, Callable] = {
    "type": choice_check(MATERIAL_TYPES),
    "color": triple_check(0.0, 1.0),
    "roughness": number_check(0.0, 1.0),
    "metal": choice_check(METALS),
}
# A darker, warm object (weathered wood, terracotta): clear ice over it reads by its
# highlights and its blue-green depth; over a pale grey one it disappears.
DEFAULT_MATERIAL = {"type": "diffuse", "color": (0.3, 0.17, 0.1), "roughness": 0.2, "metal": "Al"}


@dataclasses.dataclass(frozen=True)
class Material:
    """A validated object material (`material_from_dict`).

    Attributes
    ----------
    type : {"diffuse", "plastic", "metal"}
    color : (3,) float
        Linear RGB reflectance in [0, 1] (diffuse, plastic).
    roughness : float
        GGX alpha in [0, 1] (plastic, metal); 0 is mirror-smooth.
    metal : {"Al", "Ag", "Au", "Cu", "Cr"}
        The conductor of a metal.
    """

    type: str = DEFAULT_MATERIAL["type"]
    color: tuple = DEFAULT_MATERIAL["color"]
    roughness: float = DEFAULT_MATERIAL["roughness"]
    metal: str = DEFAULT_MATERIAL["metal"]

    def to_dict(self) -> dict[str, Any]:
        """Plain values for JSON (``done.json``'s ``object_material``) and manifests."""
        return {"type": self.type, "color": list(self.color), "roughness": self.roughness, "metal": self.metal}


def material_from_dict(values: Mapping[str, Any] | Material | None) -> Material:
    """Validate an object material: ``{type: diffuse|plastic|metal, color, roughness, metal}``.

    ``color`` is linear RGB reflectance in [0, 1]; ``roughness`` (plastic, metal) is the GGX
    alpha, 0 for a mirror-smooth coat; ``metal`` names a conductor (Al, Ag, Au, Cu, Cr).
    Missing keys take `DEFAULT_MATERIAL`'s values.

    Raises
    ------
    InputError
        Unknown key (with the nearest one) or a bad value.
    """
    if isinstance(values, Material):
        return values
    out = dict(DEFAULT_MATERIAL)
    if values is None:
        return Material()
    if not isinstance(values, Mapping):
        raise InputError(f"material: expected a mapping of {', '.join(_MATERIAL)}, got {values!r}")
    for key, value in values.items():
        if key not in _MATERIAL:
            hint = difflib.get_close_matches(str(key), list(_MATERIAL), n=1, cutoff=0.5)
            tip = f"; did you mean {hint[0]!r}?" if hint else f"; valid keys: {', '.join(_MATERIAL)}"
            raise InputError(f"material: unknown key {key!r}{tip}")
        try:
            out[key] = _MATERIAL[key](f"material.{key}", value)
        except InputError as exc:
            raise InputError(str(exc).replace("render config: ", "")) from None
    out["color"] = tuple(out["color"])
    return Material(**out)
