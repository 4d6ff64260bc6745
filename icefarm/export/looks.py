"""The scene spec's looks for formats without Mitsuba's materials and emitters (UsdPreviewSurface,
MaterialX, glTF): pure functions of a `SceneSpec` and its parts.

The object's material as metallic-roughness PBR (`pbr`), the ice's colour where a format has
no absorbing medium (`ice_color`), the perceptual roughness of icefarm's GGX alphas
(`perceptual_roughness`) and the sun as a directional light (`sun_light`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import IceLook, Material, SceneSpec

__all__ = ["METAL_F0", "TINT_DISTANCE_M", "Pbr", "ice_color", "pbr", "perceptual_roughness", "sun_light"]

# Normal-incidence reflectance (linear RGB) of Mitsuba's conductors, as a PBR metal's base
# colour: the usual table of F0 values (Hoffman, "Physically Based Shading", SIGGRAPH course).
METAL_F0 = {
    "Al": (0.913, 0.922, 0.924),
    "Ag": (0.972, 0.960, 0.915),
    "Au": (1.000, 0.766, 0.336),
    "Cu": (0.955, 0.638, 0.538),
    "Cr": (0.549, 0.556, 0.554),
}
# The ice's colour, where a format has no absorbing medium (UsdPreviewSurface): what white
# light looks like after this much ice. 10 cm: the root of a long icicle, where ice shows colour.
TINT_DISTANCE_M = 0.1


@dataclass(frozen=True)
class Pbr:
    """A manifest material as metallic-roughness PBR (UsdPreviewSurface, glTF).

    ``roughness`` is perceptual (the square root of Mitsuba's GGX alpha); ``specular`` False
    for a purely diffuse material, which has no highlight at all in Mitsuba.
    """

    base_color: tuple[float, float, float]
    metallic: float
    roughness: float
    specular: bool


def pbr(material: Material) -> Pbr:
    """`Pbr` of a validated object material (`SceneSpec.material`)."""
    if material.type == "metal":
        return Pbr(METAL_F0[material.metal], 1.0, perceptual_roughness(material.roughness), True)
    if material.type == "plastic":
        return Pbr(tuple(material.color), 0.0, perceptual_roughness(material.roughness), True)
    return Pbr(tuple(material.color), 0.0, 1.0, False)


def perceptual_roughness(alpha: float) -> float:
    """The roughness of UsdPreviewSurface and glTF, whose square is the GGX ``alpha`` icefarm's
    roughnesses are (`IceLook.roughness`, `Material.roughness`)."""
    return float(np.sqrt(alpha))


def ice_color(ice: IceLook, distance: float = TINT_DISTANCE_M) -> np.ndarray:
    """``(3,)`` linear RGB of white light after ``distance`` meters of ``ice`` (its tint times
    Beer-Lambert's absorption)."""
    return np.asarray(ice.tint) * np.exp(-np.asarray(ice.absorption) * distance)


def sun_light(spec: SceneSpec) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The spec's sun as a directional light: unit direction towards it ``(3,)``, intensity
    (W/m^2: Mitsuba's irradiance in its strongest channel) and linear RGB colour ``(3,)``
    (the irradiance's hue, its strongest channel 1); None without a sun."""
    if spec.sun is None:
        return None
    irradiance = np.asarray(spec.sun.irradiance, dtype=np.float64)
    strength = float(np.max(irradiance))
    return spec.sun.direction / np.linalg.norm(spec.sun.direction), strength, irradiance / max(strength, 1e-12)
