"""Box-modelled assets at their real size: a garden table, a park bench, a small car, a picket
fence, a street lamp, a bus shelter and a sign on a post.

Unlike the other generators these are in meters (Y-up, lowest point on y = 0) and stay
low-poly, as an artist's box-modelled asset would: boxes, tapered boxes (`frustum`) and
extruded polygons (`extrude`: slats, pickets, wheels, poles) overlapping a little where
they join, fused by one boolean union (manifold3d) into a single closed, outward-facing
manifold of tens to a few hundred faces. ``detail`` does not change them.

`HEIGHTS` holds each asset's natural height (m): the top of its highest part, which the
builders place exactly there.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ._common import DEFAULT_DETAIL, rest_on_ground
from .roof import prism

# Parts that meet overlap by this much (m), so the union never meets coplanar faces.
_SINK = 0.005


def box(lo, hi) -> trimesh.Trimesh:
    """An axis-aligned box from corner ``lo`` (3,) to corner ``hi`` (3,), in meters; 12 faces."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return trimesh.creation.box(bounds=[lo, hi])


def extrude(profile, lo: float, hi: float, axis: int) -> trimesh.Trimesh:
    """A convex polygon extruded along a coordinate axis: a closed, outward-facing solid.

    Parameters
    ----------
    profile : (n, 2) float
        Convex polygon, either winding, in the plane across ``axis``: coordinates
        ``(y, z)`` for ``axis = 0``, ``(z, x)`` for 1, ``(x, y)`` for 2 (the cyclic order,
        which keeps the solid outward-facing). Meters.
    lo, hi : float
        Extent along ``axis``, ``lo < hi``.
    axis : int
        0, 1 or 2 (x, y, z).

    Returns
    -------
    trimesh.Trimesh
        ``2 n`` vertices, ``4 n - 4`` faces.
    """
    profile = np.asarray(profile, dtype=np.float64)
    x, y = profile.T
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        profile = profile[::-1]
    n = len(profile)
    fan = np.stack([np.zeros(n - 2, dtype=np.int64), np.arange(1, n - 1), np.arange(2, n)], axis=1)
    solid = prism(profile, fan, lo, hi)
    # prism extrudes (x, y) along z; rolling the columns sends its z to ``axis``.
    vertices = np.roll(solid.vertices, (axis + 1) % 3, axis=1)
    return trimesh.Trimesh(vertices, solid.faces, process=False)


def circle(center, radius: float, sections: int) -> np.ndarray:
    """``(sections, 2)`` corners of a regular polygon around ``center`` (2,), the first one at
    angle -90 degrees, so a polygon with ``sections`` a multiple of 4 touches ``v = -radius``."""
    angle = np.deg2rad(-90.0) + 2 * np.pi * np.arange(sections) / sections
    return np.asarray(center, dtype=np.float64) + radius * np.c_[np.cos(angle), np.sin(angle)]


def frustum(bottom, top, y0: float, y1: float) -> trimesh.Trimesh:
    """A tapered box: rectangle ``bottom`` at height ``y0``, rectangle ``top`` at ``y1``.

    Parameters
    ----------
    bottom, top : (2, 2) float
        ``[[x_min, z_min], [x_max, z_max]]`` of each face, meters; ``top`` may be larger
        (an overhanging lamp shade) or smaller (a cabin, a pitched lid).
    y0, y1 : float
        ``y0 < y1``.

    Returns
    -------
    trimesh.Trimesh
        8 vertices, 12 outward-facing faces (every side is a planar trapezoid).
    """
    (bx0, bz0), (bx1, bz1) = np.asarray(bottom, dtype=np.float64)
    (tx0, tz0), (tx1, tz1) = np.asarray(top, dtype=np.float64)
    vertices = np.array([[bx0, y0, bz0], [bx1, y0, bz0], [bx1, y0, bz1], [bx0, y0, bz1],
                         [tx0, y1, tz0], [tx1, y1, tz0], [tx1, y1, tz1], [tx0, y1, tz1]])
    faces = np.array([[0, 1, 2], [0, 2, 3],                      # bottom, facing -y
                      [4, 7, 6], [4, 6, 5],                      # top, facing +y
                      [0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2],
                      [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]])
    return trimesh.Trimesh(vertices, faces, process=False)


def fuse(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean union of overlapping closed parts, set on the ground; raises if the result is
    not one closed volume (parts that do not touch)."""
    mesh = rest_on_ground(trimesh.boolean.union(parts, engine="manifold"))
    if not mesh.is_volume or mesh.body_count != 1:
        raise ValueError("asset parts do not fuse into one closed volume")
    return mesh


def table(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A square garden table 0.74 m high: a 0.9 x 0.9 m top, 3 cm thick, on four 5 cm legs
    set 5 cm in from its edges, joined by 8 cm aprons under the top."""
    top = box([-0.45, 0.71, -0.45], [0.45, 0.74, 0.45])
    legs = [box([x - 0.025, 0.0, z - 0.025], [x + 0.025, 0.71 + _SINK, z + 0.025])
            for x in (-0.375, 0.375) for z in (-0.375, 0.375)]
    aprons = [box([-0.36, 0.63, s * 0.375 - 0.01], [0.36, 0.71 + _SINK, s * 0.375 + 0.01]) for s in (-1, 1)]
    aprons += [box([s * 0.375 - 0.01, 0.63, -0.36], [s * 0.375 + 0.01, 0.71 + _SINK, 0.36]) for s in (-1, 1)]
    return fuse([top, *legs, *aprons])


def bench(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A park bench 0.95 m high and 1.6 m long: three seat slats at 0.45 m on two side
    frames (front leg, rear post rising to the top, seat bearer), two backrest slats on the
    rear posts."""
    parts = []
    for x in (-0.65, 0.65):
        parts += [box([x - 0.03, 0.0, 0.13], [x + 0.03, 0.42, 0.19]),            # front leg
                  box([x - 0.03, 0.0, -0.24], [x + 0.03, 0.95, -0.18]),          # rear post
                  box([x - 0.03, 0.36, -0.18 - _SINK], [x + 0.03, 0.42 + _SINK, 0.19])]  # bearer
    for z in (-0.17, -0.04, 0.09):                                               # seat slats, 1 cm gaps
        parts.append(box([-0.8, 0.42, z], [0.8, 0.45, z + 0.12]))
    for y in (0.6, 0.79):                                                        # backrest slats
        parts.append(box([-0.8, y, -0.18 - _SINK], [0.8, y + 0.12, -0.155]))
    return fuse(parts)


def car(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A small hatchback 1.5 m high, 3.8 m long (x, nose towards +x), 1.64 m wide: a body box
    from 0.25 to 0.85 m, a cabin tapered on every side (sloped windscreen and rear window),
    four 12-sided wheels 0.6 m across bulging 3 cm out of the body."""
    body = box([-1.9, 0.25, -0.82], [1.9, 0.85, 0.82])
    cabin = frustum([[-1.75, -0.8], [0.75, 0.8]], [[-1.55, -0.66], [-0.1, 0.66]], 0.85 - _SINK, 1.5)
    wheels = [extrude(circle([x, 0.3], 0.3, 12), z0, z1, axis=2)
              for x in (-1.25, 1.25) for z0, z1 in ((-0.85, -0.62), (0.62, 0.85))]
    return fuse([body, cabin, *wheels])


def fence(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A picket fence 1.0 m high and 2.4 m long (x): three 8 cm posts with flat tops, two
    rails at 0.25 and 0.75 m behind 12 pickets (9 cm wide at a 20 cm pitch, 2 cm thick,
    pointed tops at 0.95 m, 5 cm above the ground).

    The largest of the assets (about 800 faces): each picket notches both rails."""
    posts = [box([x - 0.04, 0.0, 0.0], [x + 0.04, 1.0, 0.08]) for x in (0.04, 1.2, 2.36)]
    rails = [box([0.0, y, 0.0], [2.4, y + 0.07, 0.04]) for y in (0.25, 0.75)]
    pickets = [extrude([[x - 0.045, 0.05], [x + 0.045, 0.05], [x + 0.045, 0.9], [x, 0.95], [x - 0.045, 0.9]],
                       -0.02, _SINK, axis=2) for x in 0.1 + 0.2 * np.arange(12)]
    return fuse([*posts, *rails, *pickets])


def lamp(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A street lamp 3.5 m high: a 0.4 m plinth, a 12 cm pole to 3.4 m, an arm reaching
    0.8 m out (+x) at 3.3 m and a lamp head hanging from its end: a 0.45 x 0.3 m box
    with a pitched lid rising to 3.5 m, its flat glass facing down."""
    plinth = extrude(circle([0.0, 0.0], 0.12, 12), 0.0, 0.4, axis=1)
    pole = extrude(circle([0.0, 0.0], 0.06, 12), 0.4 - _SINK, 3.4, axis=1)
    arm = box([0.0, 3.3, -0.03], [0.62, 3.36, 0.03])
    head = box([0.38, 3.15, -0.15], [0.83, 3.3 + _SINK, 0.15])
    lid = frustum([[0.36, -0.17], [0.85, 0.17]], [[0.55, -0.04], [0.66, 0.04]], 3.3, 3.5)
    return fuse([plinth, pole, arm, head, lid])


def shelter(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A bus shelter 2.5 m high: four 8 cm posts on a 2.8 x 1.4 m footprint, a glass back
    panel, and a 10 cm roof slab 3.4 x 2.0 m that overhangs 30 cm all round and slopes
    down to the front (+z), its top 2.5 m at the back and 2.4 m at the front."""
    depth, drop, thick = 1.0, 0.1, 0.1

    def underside(z):  # height of the slab's underside at z
        return 2.5 - thick - drop * (z + depth) / (2 * depth)

    roof = extrude([[2.5 - thick, -depth], [2.4 - thick, depth], [2.4, depth], [2.5, -depth]],  # (y, z)
                   -1.7, 1.7, axis=0)
    posts = [box([x - 0.04, 0.0, z - 0.04], [x + 0.04, underside(z) + 0.03, z + 0.04])
             for x in (-1.4, 1.4) for z in (-0.7, 0.7)]
    panel = box([-1.36 - _SINK, 0.15, -0.715], [1.36 + _SINK, 2.1, -0.685])
    return fuse([roof, *posts, panel])


def sign(detail: int = DEFAULT_DETAIL) -> trimesh.Trimesh:
    """A sign on a post, 2.2 m high: a 6 cm square post and a 0.6 x 0.6 m plate, 2 cm
    thick, whose top edge is the top of the post."""
    post = box([-0.03, 0.0, 0.0], [0.03, 2.2 - 0.02, 0.06])
    plate = box([-0.3, 1.6, -0.02], [0.3, 2.2, _SINK])
    return fuse([post, plate])


# Natural height of each asset (m): what it is built to, and measures.
HEIGHTS = {"table": 0.74, "bench": 0.95, "car": 1.5, "fence": 1.0, "lamp": 3.5, "shelter": 2.5, "sign": 2.2}
BUILDERS = {"table": table, "bench": bench, "car": car, "fence": fence, "lamp": lamp,
            "shelter": shelter, "sign": sign}
