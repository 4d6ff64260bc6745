"""A procedural sky: the environment map that gives the ice something to refract.

Clear ice shows what lies behind it, bent and flipped. A uniform sky shows nothing, so this
sky has a sharp horizon over dark ground (icicles read by the inverted horizon in them),
a blue gradient overhead, a glow around the sun and a few bright soft patches (clouds,
windows) that leave highlights in the ice from any side.
"""

from __future__ import annotations

import numpy as np

# (azimuth, elevation, width, height) in degrees and radiance of the bright patches.
_PATCHES = (
    (-60.0, 18.0, 24.0, 12.0, 3.0),
    (160.0, 32.0, 30.0, 14.0, 2.0),
    (55.0, 8.0, 14.0, 8.0, 4.0),
    (250.0, 55.0, 36.0, 16.0, 1.5),
)


def sky_directions(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (radians, ``(height, width)`` each) of each texel's centre.

    Follows Mitsuba's ``envmap`` layout in its local frame (Y up, -Z at u = 0): row 0 is
    the zenith; the local frame's X, Y, Z are the world frame's right, up, front, and
    azimuth is measured as in `camera.direction`.
    """
    theta = (np.arange(height) + 0.5) / height * np.pi  # from the zenith
    u = (np.arange(width) + 0.5) / width
    azimuth = np.pi - 2 * np.pi * u  # atan2(x, -z) = 2 pi u with x = sin(az), z = cos(az)
    az, th = np.meshgrid(azimuth, theta)
    return az, np.pi / 2 - th


def procedural_sky(width: int = 512, height: int = 256, sun_azimuth: float = 120.0,
                   sun_elevation: float = 45.0) -> np.ndarray:
    """Linear RGB radiance ``(height, width, 3)`` float32 of an equirectangular sky.

    Parameters
    ----------
    width, height : int
        Texels; ``width`` should be ``2 * height``.
    sun_azimuth, sun_elevation : float
        Degrees; a warm glow is centred there (the sun itself is a separate light).
    """
    if width < 8 or height < 4:
        raise ValueError(f"sky too small: {width}x{height}")
    az, el = sky_directions(width, height)
    s = np.clip(el / (np.pi / 2), 0.0, 1.0)[..., None]
    # Calibrated so the sky gives about 1 W/m^2 on a level surface, a third of the sun.
    # A clear winter blue down to the horizon: behind clear ice a grey sky leaves nothing
    # for the ice to bend, a blue one shows as blue highlights against the warm object.
    zenith = np.array([0.05, 0.11, 0.36])
    horizon = np.array([0.2, 0.28, 0.44])
    sky = horizon + (zenith - horizon) * np.sqrt(s)
    # A smooth step over about one degree keeps the horizon sharp in refraction.
    above = np.clip(0.5 + el / np.radians(1.0), 0.0, 1.0)[..., None]
    depth = np.clip(-el / (np.pi / 2), 0.0, 1.0)[..., None]
    ground = np.array([0.06, 0.055, 0.05]) * (1.0 - 0.6 * depth)
    rgb = ground + (sky - ground) * above

    def cos_to(a0, e0):
        return (np.cos(el) * np.cos(np.radians(e0)) * np.cos(az - np.radians(a0))
                + np.sin(el) * np.sin(np.radians(e0)))

    sun = np.arccos(np.clip(cos_to(sun_azimuth, sun_elevation), -1, 1))
    rgb += np.array([2.0, 1.8, 1.5]) * np.exp(-(sun / np.radians(6.0)) ** 2)[..., None]
    rgb += np.array([0.15, 0.13, 0.1]) * np.exp(-(sun / np.radians(30.0)) ** 2)[..., None]

    for a0, e0, w, h, value in _PATCHES:
        daz = np.angle(np.exp(1j * (az - np.radians(a0))))  # wrapped to (-pi, pi]
        dx = np.abs(daz) * np.cos(el) / np.radians(w / 2)
        dy = np.abs(el - np.radians(e0)) / np.radians(h / 2)
        soft = np.clip(1.0 - np.maximum(dx, dy), 0.0, 0.25) / 0.25  # flat top, soft edge
        rgb += value * (soft * above[..., 0])[..., None]
    return rgb.astype(np.float32)
