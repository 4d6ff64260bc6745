"""The ice-aware path tracer as Mitsuba's ``icepath`` plugin: its class per JIT variant
(`integrator_class`), an instance with a job's settings (`ice_integrator`, the ice's look
from its `SceneSpec`), and the ice's medium read back from a loaded scene, to check a
``scene.xml`` against its spec (`medium_coefficients`).

What it samples, and why (transmissive shadows through ice, the medium inside it), is in
`icefarm.scene.icepath`.
"""

from __future__ import annotations

import functools

from .config import IceLook, IceMedium
from .icepath import FEATURE_CHANNELS, MAX_CROSSINGS, RR_DEPTH, IcePathMethods, rgb_coefficients

__all__ = ["FEATURE_CHANNELS", "MAX_CROSSINGS", "PLUGIN_NAME", "ice_integrator", "integrator_class",
           "medium_coefficients"]

PLUGIN_NAME = "icepath"
_JIT_PREFIXES = ("llvm_", "cuda_")


@functools.cache
def integrator_class(variant: str) -> type:
    """The ``IcePathIntegrator`` class of JIT ``variant`` (made active if it is not).

    The class is a ``mitsuba.SamplingIntegrator`` built once per variant, and registered
    as the ``icepath`` plugin, so ``{"type": "icepath", ...}`` dicts and
    ``<integrator type="icepath">`` XML load it too.

    Parameters
    ----------
    variant : str
        ``llvm_ad_rgb``, ``cuda_ad_rgb`` (any ``llvm_*``/``cuda_*`` RGB variant).

    Raises
    ------
    ValueError
        A scalar (non-JIT) or non-RGB (mono, spectral) variant.
    """
    if not variant.startswith(_JIT_PREFIXES) or not variant.endswith("_rgb"):
        raise ValueError(f"the ice integrator needs a JIT RGB variant (llvm_ad_rgb, cuda_ad_rgb), "
                         f"got {variant!r}")
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
    methods = {k: v for k, v in vars(IcePathMethods).items()
               if k in ("__init__", "__doc__") or not k.startswith("__")}
    # @dr.syntax rewrites their while loops into Dr.Jit symbolic loops; it is applied
    # here because drjit must not be imported before `variants.pick_variant` ran.
    methods["_shadow"] = dr.syntax(IcePathMethods._shadow)
    methods["sample"] = dr.syntax(IcePathMethods.sample)
    cls = type("IcePathIntegrator", (mi.SamplingIntegrator,), methods)
    mi.register_integrator(PLUGIN_NAME, lambda props: cls(props))
    return cls


def ice_integrator(variant: str, max_depth: int = 12, *, ice: IceLook | None = None,
                   medium: IceMedium | None = None, features: bool = False, max_crossings: int = MAX_CROSSINGS):
    """The ice-aware path tracer for ``variant``, or None on scalar variants.

    Render with ``mi.render(scene, sensor=i, spp=spp, integrator=it)``; on None keep the
    scene's own ``path`` integrator.

    Parameters
    ----------
    variant : str
        The Mitsuba variant in use (made active if it is not).
    max_depth : int
        Longest path in scattering vertices, as ``path``'s ``max_depth`` (-1: unbounded);
        ice pass-throughs do not count.
    ice : IceLook, optional
        The ice's look: its ``ior`` (all ice, for the pass-through Fresnel term) and ``tint``
        (RGB transmittance per crossing in [0, 1], the XML's ``specular_transmittance``) are
        read. Default `IceLook`'s.
    medium : IceMedium, optional
        What fills the ice: absorption (R, G, B) and scattering coefficients per scene unit
        (meter), as `icefarm.scene.config.ice_medium` gives them for the spec's ice. Default
        none: clear ice.
    features : bool
        Also write the denoiser's feature buffers (`FEATURE_CHANNELS`): ``mi.render``
        then returns these six channels after the three of RGB.
    max_crossings : int
        Pass-throughs per path segment and per shadow ray before the light is absorbed.

    Returns
    -------
    mitsuba.SamplingIntegrator or None

    Raises
    ------
    ValueError
        Out-of-range parameters, or a JIT variant that is not RGB.
    """
    if not variant.startswith(_JIT_PREFIXES):
        return None
    import mitsuba as mi

    cls = integrator_class(variant)
    props = mi.Properties()
    props["max_depth"] = int(max_depth)
    props["rr_depth"] = RR_DEPTH
    ice = IceLook() if ice is None else ice
    props["ior"] = float(ice.ior)
    props["tint"] = mi.ScalarColor3f(*(float(t) for t in ice.tint))
    props["max_crossings"] = int(max_crossings)
    props["sigma_a"] = mi.ScalarColor3f(*rgb_coefficients(0.0 if medium is None else medium.absorption, "sigma_a"))
    props["sigma_s"] = mi.ScalarColor3f(*rgb_coefficients(0.0 if medium is None else medium.scattering, "sigma_s"))
    props["features"] = bool(features)
    return cls(props)


def medium_coefficients(scene, shape_id: str = "ice") -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Absorption and scattering per scene unit ``(sigma_a, sigma_s)`` of the interior
    medium of shape ``shape_id`` in a loaded Mitsuba scene; None without one.

    Evaluated at the medium's origin: homogeneous media (what icefarm writes) are the
    same everywhere.
    """
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    for shape in scene.shapes():
        if shape.id() != shape_id:
            continue
        medium = shape.interior_medium()
        if medium is None:
            return None
        mei = dr.zeros(mi.MediumInteraction3f)
        mei.t = 0.0  # valid
        sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei, True)
        s = np.array(sigma_s, dtype=np.float64).reshape(-1)[:3]
        t = np.array(sigma_t, dtype=np.float64).reshape(-1)[:3]
        if s.size == 1:
            s, t = np.repeat(s, 3), np.repeat(t, 3)
        return tuple(float(x) for x in np.maximum(t - s, 0.0)), tuple(float(x) for x in s)
    return None
