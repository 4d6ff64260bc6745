"""Denoise a render with Intel Open Image Denoise, guided by albedo and normal features.

Lookdev renders few samples and denoises them: OIDN's ray-tracing filter, given what
each pixel shows (its albedo and normal, from `integrator.FEATURE_CHANNELS`), removes the
Monte Carlo noise and keeps edges and textures. Through the ice those features are what
the ice shows (the object or ground behind it, weighted by what the ice lets through), so
refracted detail keeps its edges too.

OIDN wants every pixel's own samples: a denoised render is box-filtered
(``scene.xml``'s ``rfilter``), and the denoised image then gets the Gaussian pixel
filter Mitsuba gives other renders (`PIXEL_FILTER_SIGMA`), so both look equally sharp.
The albedo is noisy where the path chose between reflection and refraction, so the
filter is told its guides are noisy (``cleanAux`` off), and they go in as they are:
denoising the albedo first (OIDN's prefiltering) cost as much as the denoising itself
(0.62 against 0.65 s a 480 x 360 view on 2 cores) for 0.07-0.19 dB (the 0.3 m bunny and
the 1.5 m car, both views, three seeds each, against 512 and 256 spp); the clean-guide
network costs 2.4 times as long for no gain here.

Measured on the 0.3 m bunny at lookdev, 16 spp denoised, against 512 spp undenoised: PSNR
43.6 dB (main view) and 41.4 dB (ice view), against 38.4 and 35.2 dB for the same 16 spp
undenoised (`icefarm bench render` reports the denoiser's seconds per view).
"""

from __future__ import annotations

import functools

import numpy as np

PIXEL_FILTER_SIGMA = 0.5  # pixels: Mitsuba's default Gaussian reconstruction filter


def denoise(rgb: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None) -> np.ndarray:
    """The denoised linear image of ``rgb``.

    Parameters
    ----------
    rgb : (h, w, 3) float
        Linear radiance (HDR: values above 1 are kept).
    albedo : (h, w, 3) float, optional
        What each pixel shows, in [0, 1]; needed with ``normal``.
    normal : (h, w, 3) float, optional
        Shading normals, world space, in [-1, 1] (zero where nothing is shown).

    Returns
    -------
    (h, w, 3) float32
        Denoised, then filtered by a Gaussian of `PIXEL_FILTER_SIGMA` pixels.

    Raises
    ------
    ValueError
        Shapes that differ, or a normal without an albedo.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be (h, w, 3), got {rgb.shape}")
    if normal is not None and albedo is None:
        raise ValueError("OIDN takes a normal only with an albedo")
    for name, aux in (("albedo", albedo), ("normal", normal)):
        if aux is not None and np.shape(aux) != rgb.shape:
            raise ValueError(f"{name} must be {rgb.shape} like rgb, got {np.shape(aux)}")
    return _denoise(rgb, albedo, normal)


def _denoise(rgb, albedo, normal) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    images = {"color": np.maximum(_f32(rgb), 0.0)}
    if albedo is not None:
        images["albedo"] = np.clip(_f32(albedo), 0.0, 1.0)
    if normal is not None:
        images["normal"] = np.clip(_f32(normal), -1.0, 1.0)
    out = _run(images, hdr=True)
    return gaussian_filter(out, (PIXEL_FILTER_SIGMA, PIXEL_FILTER_SIGMA, 0.0), truncate=4.0)


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0), dtype=np.float32)


@functools.cache
def _filters():
    """One OIDN device and its ``RT`` filter, per process: a filter's first commit builds its
    network, the slow part; later commits with new images of the same size are cheap."""
    import pyoidn

    device = pyoidn.Device()
    device.commit()
    return device, pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)


def _run(images: dict[str, np.ndarray], **flags: bool) -> np.ndarray:
    """Run the filter over ``images`` (``color``, with ``albedo`` and ``normal`` where given)
    and return its output."""
    import pyoidn

    device, flt = _filters()
    out = np.empty_like(images["color"])
    for name in ("color", "albedo", "normal"):
        if name in images:
            flt.set_image(name, images[name], pyoidn.OIDN_FORMAT_FLOAT3)
        else:
            flt.unset_image(name)
    flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
    for name, value in flags.items():
        flt.set_bool(name, value)
    flt.set_quality(pyoidn.OIDN_QUALITY_HIGH)
    flt.commit()
    flt.execute()
    error = device.get_error()
    if error:
        raise RuntimeError(f"Open Image Denoise failed: {error}")
    return out


def denoiser_version() -> str:
    """``OIDN <major>.<minor>.<patch>`` of the library that denoises."""
    from pyoidn import version

    return f"OIDN {version.oidn_version}"
