"""Where the ice is densest, and a view zoomed onto it.

Clear icicles a few millimetres wide are a few pixels wide in a view of the whole object:
too thin to judge. An ice view keeps the main view's camera position and turns and zooms
it onto the densest cluster of icicles, close enough that they are several pixels wide.

Icicles are told from glaze by their distance from the object (`ice_focus`); horizontal
sections through them measure their diameter and place them (`section_diameters`); rays
cast at them against the object tell those the camera sees from those behind it
(`visible`); the window of the picture holding most seen icicles, and fewest hidden ones
(a wheel or a post in front of them), is then framed (`zoom_on_ice`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .camera import Camera, along

ICICLE_PX = 14.0  # icicle width (pixels) an ice view aims for (12 at least, with some slack)
MIN_ICICLE_PX = 12.5  # ... and zooms out to at most (12 at least, with slack), to show long icicles whole
MIN_ZOOM = 2.5  # an ice view is always a detail: at least this much closer than the full view
MAX_ZOOM = 40.0
FRAME_FILL = 0.95  # `_frame_lengthwise`: the framed icicles fill at most this share of the window's height ...
ROOT_LIFT = 0.25  # ... and this share of what is left of it goes below them (the object they hang from shows above)
JOIN = 3.0  # `_joined`: samples of one icicle lie within this many times their median spacing of another
FOCUS_SAMPLES = 8_000  # ice vertices looked at to find the icicles
SECTIONS = 10  # horizontal sections that find the icicles and measure their diameter
THIN = 2.5  # a section up to this times the median width is an icicle's, wider ones are lumps
OBJECT_POINTS = 10_000  # object vertices (at most) and ...
OBJECT_SAMPLES = 4_000  # ... points on its faces that tell icicles from glaze
AXIS_REACH = 1.5  # icicles' ice lies within this many times the clearance of their axes


@dataclass(frozen=True)
class IceFocus:
    """Where the ice is densest, for a view zoomed on it.

    Attributes
    ----------
    points : (n, 3) float
        Where the icicles are: given their axes, the axes' points away from the object;
        else the centres of their horizontal sections (or, when too few were found,
        sampled ice vertices away from the object; for glaze alone, sampled ice vertices).
    diameter : float or None
        Median icicle diameter (m) measured on horizontal sections; None without icicles.
    icicles : (k, 3) float
        Sampled ice vertices away from the object, the icicles' whole length (``points``
        lie on a few sections of them): how far up and down the icicles framed run.
    clearance : float
        How far from the object (m) ice counts as icicles: ``icicles`` start that far below
        where they hang from.
    """

    points: np.ndarray
    diameter: float | None
    icicles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    clearance: float = 0.0


def _edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Median edge length (m) of the mesh's faces (their first edges: whatever the faces'
    order, unlike every so-many of them)."""
    faces = np.asarray(faces)
    d = vertices[faces[:, 1]] - vertices[faces[:, 0]]
    return float(np.median(np.sqrt(np.einsum("kd,kd->k", d, d))))


def spread_sample(points: np.ndarray, count: int) -> np.ndarray:
    """About ``count`` of ``points`` (n, 3), in coordinate order: the same ones for the same
    points in any order. Those whose single-precision coordinates hash to a multiple of
    ``n // count``: every so-many in memory order would move an ice view 35 cm along the 0.4 m
    fountain's rim when marching cubes' batches change only the ice vertices' order."""
    points = np.asarray(points, dtype=np.float64)
    step = len(points) // count
    if step > 1:
        bits = np.ascontiguousarray(points, dtype=np.float32).view(np.uint32).astype(np.uint64)
        mixed = (bits[:, 0] * np.uint64(0x9E3779B1)) ^ (bits[:, 1] * np.uint64(0x85EBCA77)) ^ \
            (bits[:, 2] * np.uint64(0xC2B2AE3D))
        mixed ^= mixed >> np.uint64(29)
        points = points[(mixed * np.uint64(0xBF58476D1CE4E5B9) >> np.uint64(32)) % np.uint64(step) == 0]
    return points[np.lexsort(points.T[::-1])]


def slab_levels(heights: np.ndarray, levels: int = SECTIONS) -> np.ndarray:
    """Heights of ``levels`` horizontal sections across the inner 80 % of ``heights``."""
    lo, hi = np.quantile(heights, [0.1, 0.9])
    return np.linspace(lo, hi, levels)


def in_slabs(heights: np.ndarray, levels: np.ndarray, thickness: float) -> np.ndarray:
    """Index of the slab (``thickness`` thick, centred on ``levels``) each height is in, -1 for none."""
    if len(levels) == 1:
        k = np.zeros(len(heights), dtype=np.int64)
    else:
        delta = (levels[-1] - levels[0]) / (len(levels) - 1)
        if delta <= 0:
            k = np.zeros(len(heights), dtype=np.int64)
        else:
            k = np.clip(np.rint((heights - levels[0]) / delta), 0, len(levels) - 1).astype(np.int64)
    return np.where(np.abs(heights - levels[k]) <= 0.5 * thickness, k, -1)


def dilated(grid: np.ndarray) -> np.ndarray:
    """``grid`` (h, w) bool dilated by a 3 x 3 square: ``ndimage.binary_dilation(grid,
    np.ones((3, 3), bool))``, as shifted ORs along each axis (a 2000 x 2000 grid: 8 ms against
    76 ms; the test compares them)."""
    rows = grid.copy()
    rows[1:] |= grid[:-1]
    rows[:-1] |= grid[1:]
    out = rows.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


def section_diameters(points: np.ndarray, slab: np.ndarray, frame: np.ndarray,
                      spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Widths (m) and centres of the icicles' horizontal sections.

    Parameters
    ----------
    points : (n, 3) float
        Ice vertices (away from the object) in thin horizontal slabs.
    slab : (n,) int
        Each point's slab (`in_slabs`).
    frame : (3, 3) float
        World frame rows (right, up, front).
    spacing : float
        The mesh's edge length: in a slab, points closer than about two of it are joined,
        and each group's width is the smaller side of its bounding box across right and
        front, an icicle's diameter, also when it leans.

    Returns
    -------
    widths : (k,) float
    centres : (k, 3) float
        The mean of each section's points.
    """
    right, _, front = frame
    widths, centres = [], []
    for k in np.unique(slab[slab >= 0]):
        q = points[slab == k]
        if len(q) < 4:
            continue
        xy = np.column_stack([along(q, right), along(q, front)])
        ij = np.floor((xy - xy.min(axis=0)) / spacing).astype(np.int64)
        shape = ij.max(axis=0) + 1
        if shape[0] * shape[1] > 4_000_000:  # too wide a slab for a grid of that size
            continue
        grid = np.zeros(shape, dtype=bool)
        grid[ij[:, 0], ij[:, 1]] = True
        labels, _ = ndimage.label(dilated(grid))
        lab = labels[ij[:, 0], ij[:, 1]]
        order = np.argsort(lab, kind="stable")
        lab, xy, q = lab[order], xy[order], q[order]
        starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
        sizes = np.diff(np.r_[starts, len(lab)])
        span = np.maximum.reduceat(xy, starts) - np.minimum.reduceat(xy, starts)
        keep = sizes >= 4
        widths.append(span[keep].min(axis=1))
        centres.append((np.add.reduceat(q, starts) / sizes[:, None])[keep])
    if not widths:
        return np.zeros(0), np.zeros((0, 3))
    return np.concatenate(widths), np.concatenate(centres)


def ice_focus(ice_vertices: np.ndarray, ice_faces: np.ndarray, object_points: np.ndarray,
              frame: np.ndarray, size: float, axes: np.ndarray | None = None) -> IceFocus | None:
    """The icicles of a scene: ice away from the object, and how thick they are.

    Parameters
    ----------
    ice_vertices, ice_faces : arrays
        The ice mesh (meters).
    object_points : (m, 3) float
        Points on the object's surface (its vertices and samples of its faces).
    frame : (3, 3) float
        World frame rows (right, up, front).
    size : float
        Size of the scene (m): ice further than 2 % of it (at least 4 mm, and three
        times the spacing of ``object_points``) from the object counts as icicles ...
    axes : (k, 3) float, optional
        ... and, given points along the icicles' axes (the trajectories), only ice within
        `AXIS_REACH` times that distance of one (icicles' roots can be wider than it): glaze
        thicker than it (2 cm on a 0.3 m bunny's back) away from the icicles is not one.

    Returns
    -------
    IceFocus or None
        None without ice.
    """
    # In single precision, as ice.ply keeps them: `icefarm render` finds the job's icicles.
    vertices = np.asarray(ice_vertices, dtype=np.float32).astype(np.float64)
    if len(vertices) == 0:
        return None
    sample = spread_sample(vertices, FOCUS_SAMPLES)
    tree = cKDTree(object_points)
    gap = float(np.median(tree.query(object_points[:: max(1, len(object_points) // 2000)], k=2)[0][:, 1]))
    reach = max(0.02 * size, 3.0 * gap, 0.004)
    axes = None if axes is None else np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    axis_tree = cKDTree(axes) if axes is not None and len(axes) else None

    def hanging(q: np.ndarray) -> np.ndarray:  # away from the object (and on an icicle's axis)
        out = ~np.isfinite(tree.query(q, distance_upper_bound=reach)[0])
        if axis_tree is not None:
            out[out] = np.isfinite(axis_tree.query(q[out], distance_upper_bound=AXIS_REACH * reach)[0])
        return out

    far = hanging(sample)
    if far.sum() < 20:  # glaze alone: the densest ice is anywhere on it
        return IceFocus(points=sample, diameter=None)
    icicles = sample[far]
    # Sections through every vertex of the icicles: thin slabs, then away from the object.
    up = frame[1]
    spacing = _edge_length(vertices, np.asarray(ice_faces))
    levels = slab_levels(along(icicles, up))
    slab = in_slabs(along(vertices, up), levels, spacing)
    lo, hi = icicles.min(axis=0) - reach, icicles.max(axis=0) + reach
    pick = np.flatnonzero(slab >= 0)
    pick = pick[np.all((vertices[pick] >= lo) & (vertices[pick] <= hi), axis=1)]
    pick = pick[hanging(vertices[pick])]
    widths, centres = section_diameters(vertices[pick], slab[pick], frame, spacing)
    if len(widths) == 0:
        return IceFocus(points=icicles, diameter=None)
    diameter = float(np.median(widths))
    thin = widths <= THIN * diameter  # icicles, not lumps of ice
    points = centres[thin] if thin.sum() >= 3 else icicles
    if axis_tree is not None:
        # Where the icicles hang, from their axes: those do not move when only the ice's
        # surface does (impurity, ripples, glaze), and the ice view framed from them stays
        # put; the sections' centres would move the car's and the fountain's ice views to other
        # icicles when a change to the ripples moves vertices by a millimetre.
        hung = axes[~np.isfinite(tree.query(axes, distance_upper_bound=reach)[0])]
        if len(hung) >= 3:
            points = hung
    return IceFocus(points=points, diameter=diameter, icicles=icicles, clearance=reach)


def visible(camera: Camera, points: np.ndarray, cast, tolerance: float) -> np.ndarray:
    """Which ``points`` (k, 3) the object does not hide from ``camera``: a ray from the
    camera to each, cast against the object (``cast``, an `icefarm.spatial.ray_caster` of
    it), hits nothing nearer than the point less ``tolerance`` (m).

    Rays, not a z-buffer of splatted surface points, whose empty cells hide nothing: the big
    flat faces of a car's wheel, a few samples each, would let the ice view frame the icicles
    behind it.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ray = points - camera.origin
    distance = np.linalg.norm(ray, axis=1)
    ok = distance > 0
    out = ok.copy()
    hit, _ = cast(np.broadcast_to(camera.origin, (int(ok.sum()), 3)), ray[ok] / distance[ok, None])
    out[ok] = hit >= distance[ok] - tolerance
    return out


def pixel_size(camera: Camera, point: np.ndarray, width: int) -> float:
    """Meters per pixel at ``point`` for ``camera`` rendering ``width`` pixels across."""
    depth = float((np.asarray(point) - camera.origin) @ camera.forward)
    return 2.0 * max(depth, 1e-9) * np.tan(np.radians(camera.fov_x) / 2) / width


def zoom_on_ice(full: Camera, focus: IceFocus, width: int, height: int, cast=None) -> Camera:
    """A camera at ``full``'s position turned and zoomed onto the densest icicles.

    The zoom makes icicles of ``focus.diameter`` about `ICICLE_PX` pixels wide (at least
    `MIN_ZOOM`, at most `MAX_ZOOM` times closer than ``full``); the window of the full
    picture it then shows is placed where it holds the most icicle points, less those the
    object hides there (``cast``, a ray caster of the object, `visible`; None: none hidden):
    the icicles behind a car's wheel would frame the wheel.
    """
    pixels = full.project(focus.points, width, height)
    ahead = along(focus.points - full.origin, full.forward) > 0
    inside = ahead & (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
    hidden = np.zeros(len(pixels), dtype=bool)
    if cast is not None and inside.any():
        span = float(np.ptp(focus.points, axis=0).max())
        tolerance = max(2.0 * (focus.diameter or 0.0), 0.01 * span)
        seen = np.zeros(len(pixels), dtype=bool)
        seen[inside] = visible(full, focus.points[inside], cast, tolerance)
        if seen.any():
            hidden = inside & ~seen
            inside = seen
    if not inside.any():
        return full
    # Hidden icicles count against a window: something stands in front of them.
    counted = inside | hidden
    pixels, points, own = pixels[counted], focus.points[counted], inside[counted]
    weight = np.where(own, 1.0, -1.0)
    zoom = MIN_ZOOM
    if focus.diameter:
        centre = np.median(points[own], axis=0)
        seen_px = focus.diameter / pixel_size(full, centre, width)
        zoom = max(MIN_ZOOM, ICICLE_PX / max(seen_px, 1e-9))
    zoom = min(zoom, MAX_ZOOM)
    # Best window: weights in bins a quarter of the window, summed over 4 x 4 bins. The
    # window searched is the zoom's to the nearest power of sqrt 2: the icicles' measured
    # width moves with their ripples, and a grid of bins that moved with it would frame other
    # icicles.
    win = np.array([width, height]) / 2.0 ** (np.round(2.0 * np.log2(zoom)) / 2.0)
    bins = win / 4
    ij = np.floor(pixels / bins).astype(np.int64)
    shape = ij.max(axis=0) + 1
    counts = np.zeros(shape + 1)
    np.add.at(counts, (ij[:, 0] + 1, ij[:, 1] + 1), weight)
    cum = counts.cumsum(0).cumsum(1)
    k = 4
    a, b = min(k, shape[0]), min(k, shape[1])
    sums = cum[a:, b:] - cum[:-a, b:] - cum[a:, :-b] + cum[:-a, :-b]
    own_count = np.zeros(shape + 1)  # a window must hold seen icicles
    np.add.at(own_count, (ij[own, 0] + 1, ij[own, 1] + 1), 1)
    oc = own_count.cumsum(0).cumsum(1)
    sums = np.where(oc[a:, b:] - oc[:-a, b:] - oc[a:, :-b] + oc[:-a, :-b] > 0, sums, -np.inf)
    i, j = np.unravel_index(np.argmax(sums), sums.shape)
    sel = own & (ij[:, 0] >= i) & (ij[:, 0] < i + a) & (ij[:, 1] >= j) & (ij[:, 1] < j + b)
    pixels, points = pixels[own], points[own]
    sel = sel[own]
    cx, cy = np.median(pixels[sel], axis=0)
    if focus.diameter:  # the zoom again, for the icicles framed (nearer or farther than all's middle)
        seen = focus.diameter / pixel_size(full, np.median(points[sel], axis=0), width)
        zoom = min(max(MIN_ZOOM, ICICLE_PX / max(seen, 1e-9)), MAX_ZOOM)
    cy, zoom = _frame_lengthwise(full, focus, points[sel], cx, cy, zoom, width, height)
    right = np.cross(full.forward, full.up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, full.forward)
    tx, ty = np.tan(np.radians(full.fov_x) / 2), np.tan(np.radians(full.fov_y) / 2)
    u, v = 2 * cx / width - 1, 1 - 2 * cy / height
    direction = full.forward + u * tx * right + v * ty * cam_up
    direction /= np.linalg.norm(direction)
    depth = float(np.median((points[sel] - full.origin) @ direction))
    fov_x = float(np.degrees(2 * np.arctan(tx / zoom)))
    fov_y = float(np.degrees(2 * np.arctan(ty / zoom)))
    return Camera(origin=full.origin, target=full.origin + direction * max(depth, 1e-6), up=full.up,
                  fov_x=fov_x, fov_y=fov_y, near=full.near, far=full.far)


def _frame_lengthwise(full: Camera, focus: IceFocus, aimed: np.ndarray, cx: float, cy: float, zoom: float,
                      width: int, height: int) -> tuple[float, float]:
    """The picture row (of ``full``'s) to centre an ice view on, and its zoom, so that the
    icicles it aims at show whole, from where they leave the object to their tips: sections
    through them (``aimed``) can lie at their tips only, and aiming there leaves a lamp's
    icicles cut off at the frame's top over an empty sky.

    The icicles' samples joined to the aimed sections (`_joined`) and within ``2 diameter``
    across of one, in the window's columns, give their extent down the picture, up to
    ``focus.clearance`` above the highest (where they leave the object). Icicles longer
    than `FRAME_FILL` of the window zoom it out, down to `MIN_ICICLE_PX` wide icicles;
    past that it shows their tips at its foot and as much above them as fits.
    """
    if not focus.diameter or len(focus.icicles) < 2 or len(aimed) == 0:
        return cy, zoom
    same = _joined(focus.icicles, aimed, focus.diameter)
    up = full.up / np.linalg.norm(full.up)

    def across(p):  # positions across the vertical
        return p - np.outer(p @ up, up)

    # and straight above or below an aimed section: not the thick glaze they are joined to
    if len(same):
        apart, _ = cKDTree(across(aimed)).query(across(same), distance_upper_bound=2.0 * focus.diameter)
        same = same[np.isfinite(apart)]
    if len(same) == 0:
        return cy, zoom
    px = full.project(same, width, height)
    px = px[np.abs(px[:, 0] - cx) <= width / zoom / 2]
    if len(px) == 0:
        return cy, zoom
    top, bottom = float(px[:, 1].min()), float(px[:, 1].max())
    root = top - focus.clearance / pixel_size(full, np.median(same, axis=0), width)
    span = bottom - root
    seen = focus.diameter / pixel_size(full, np.median(aimed, axis=0), width)  # icicle px in the full view
    zoom = min(zoom, max(FRAME_FILL * height / max(span, 1e-9), MIN_ICICLE_PX / max(seen, 1e-9), MIN_ZOOM))
    window = height / zoom
    room = FRAME_FILL * window
    margin = 0.5 * (window - room)
    if span <= room:  # whole, nudged up towards the object they hang from
        return (root + bottom) / 2 - 0.5 * (room - span) * ROOT_LIFT, zoom
    # longer: their tips at the foot of the window, as much above them as fits (a curtain of
    # metre-long icicles framed from the top is a wall of blue ice)
    return bottom + margin - 0.5 * window, zoom


def _joined(samples: np.ndarray, aimed: np.ndarray, diameter: float) -> np.ndarray:
    """The ``samples`` (k, 3) of the icicles that ``aimed`` points (on their sections) lie
    on: those joined to them by chains of samples under `JOIN` times the samples' median
    spacing apart (other icicles higher up in the same columns of the picture are not)."""
    tree = cKDTree(samples)
    reach = JOIN * float(np.median(tree.query(samples, k=2)[0][:, 1]))
    pairs = tree.query_pairs(reach, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(samples),) * 2)
    _, part = connected_components(graph, directed=False)
    near = np.isfinite(cKDTree(aimed).query(samples, distance_upper_bound=diameter + reach)[0])
    return samples[np.isin(part, np.unique(part[near]))]


def surface_points(mesh: trimesh.Trimesh, count: int = OBJECT_SAMPLES,
                    most: int = OBJECT_POINTS) -> np.ndarray:
    """Points on ``mesh``'s surface, the same for the same surface: its vertices (at most
    ``most``), and ``count`` samples of its faces by area when its faces are big (the
    median edge over 1 % of the mesh's size), which its vertices alone would leave bare.

    Past ``most``, every so many of the distinct vertices in coordinate order (rounded to
    single precision, as ``object.ply`` stores them): the job's mesh and the one
    ``icefarm render`` reads back (its vertices split along creases, then merged again, in
    another order) give the same points, and so frame the same views."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    some = faces[:: max(1, len(faces) // 1000)]
    edge = float(np.median(np.linalg.norm(vertices[some[:, 1]] - vertices[some[:, 0]], axis=1)))
    kept = vertices
    if len(vertices) > most:
        distinct = np.unique(vertices.astype(np.float32), axis=0).astype(np.float64)
        kept = distinct[:: -(-len(distinct) // most)]
    if edge <= 0.01 * float(np.ptp(vertices, axis=0).max()):
        return kept
    tri = vertices[faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        return kept
    rng = np.random.default_rng(0)
    cumulative = np.cumsum(area)
    face = np.minimum(np.searchsorted(cumulative, rng.random(count) * cumulative[-1]), len(faces) - 1)
    r = rng.random((count, 2))
    flip = r.sum(axis=1) > 1
    r[flip] = 1 - r[flip]
    t = tri[face]
    samples = t[:, 0] + r[:, :1] * (t[:, 1] - t[:, 0]) + r[:, 1:] * (t[:, 2] - t[:, 0])
    return np.vstack([kept, samples])
