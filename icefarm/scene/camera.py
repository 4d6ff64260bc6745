"""Cameras framed on the object and its ice, with "up" taken from gravity.

Directions are given as azimuth/elevation in a world frame built from gravity: ``up`` is
minus gravity, ``front`` the first of +Z, -Y, +X that is not close to ``up`` (so Y-up
scenes look along -Z and Z-up scenes along +Y, as their authors expect), and
``right = up x front``. Azimuth 0 puts the camera in front, 90 on the right side.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError


@dataclass(frozen=True)
class Camera:
    """A perspective camera in meters.

    Attributes
    ----------
    origin, target, up : (3,) float
        Eye position, point looked at, up vector (world space, right-handed).
    fov_x, fov_y : float
        Horizontal and vertical field of view, degrees.
    near, far : float
        Clip distances, meters.
    """

    origin: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_x: float
    fov_y: float
    near: float
    far: float

    @property
    def forward(self) -> np.ndarray:
        d = self.target - self.origin
        return d / np.linalg.norm(d)

    def project(self, points: np.ndarray, width: int, height: int) -> np.ndarray:
        """Pixel coordinates ``(n, 2)`` (x right, y down) of world ``points`` ``(n, 3)``."""
        fwd = self.forward
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
        cam_up = np.cross(right, fwd)
        q = np.asarray(points, dtype=np.float64) - self.origin
        z = q @ fwd
        u = (q @ right) / (z * np.tan(np.radians(self.fov_x) / 2))
        v = (q @ cam_up) / (z * np.tan(np.radians(self.fov_y) / 2))
        return np.column_stack([(u + 1) * width / 2, (1 - v) * height / 2])


def world_frame(gravity) -> np.ndarray:
    """Rows ``right, up, front`` ``(3, 3)``: an orthonormal right-handed frame with up = -gravity.

    Raises
    ------
    ValueError
        Gravity is zero or not finite.
    """
    g = np.asarray(gravity, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(g)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"gravity must be a non-zero finite vector, got {gravity!r}")
    up = -g / norm
    for ref in ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)):
        ref = np.asarray(ref)
        if abs(ref @ up) < 0.9:
            break
    front = ref - (ref @ up) * up
    front /= np.linalg.norm(front)
    return np.stack([np.cross(up, front), up, front])


def direction(frame: np.ndarray, azimuth: float, elevation: float) -> np.ndarray:
    """Unit vector ``(3,)`` at ``azimuth``/``elevation`` degrees in ``frame`` (see `world_frame`)."""
    az, el = np.radians(azimuth), np.radians(elevation)
    right, up, front = frame
    return np.cos(el) * (np.sin(az) * right + np.cos(az) * front) + np.sin(el) * up


def framing_points(points: np.ndarray) -> np.ndarray:
    """The points that matter for framing ``(m, 3)``: the convex hull's vertices."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 64:
        return points
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:  # flat or degenerate: every point counts
        return points


def fit(points: np.ndarray, view_dir: np.ndarray, up: np.ndarray, fov_x: float, fov_y: float,
        margin: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Tightest camera looking along ``-view_dir`` that shows all ``points`` ``(n, 3)``.

    For a fixed direction the distance and the sideways shift of the target that fit every
    point inside ``margin`` of the frame solve a small linear problem per image axis:
    ``|x - s| <= k (a + d)`` for each point (``x`` sideways, ``a`` depth past the target).

    Returns
    -------
    origin, target : (3,) float
    """
    fwd = -np.asarray(view_dir, dtype=np.float64)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, fwd)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    q = points - centre
    a = q @ fwd
    shift, dist = [], 0.0
    for axis, fov in ((right, fov_x), (cam_up, fov_y)):
        k = np.tan(np.radians(fov) / 2) * margin
        x = q @ axis
        hi, lo = np.max(x - k * a), np.min(x + k * a)
        dist = max(dist, (hi - lo) / (2 * k))
        shift.append((hi + lo) / 2)
    # Never inside the bounding sphere: the near plane must clear the geometry.
    radius = np.linalg.norm(q, axis=1).max()
    dist = max(dist, 1.05 * radius, 1e-6)
    target = centre + shift[0] * right + shift[1] * cam_up
    return target - fwd * dist, target


def frame_view(points: np.ndarray, gravity, azimuth: float, elevation: float, aspect: float,
               fov_y: float = 30.0, ground: float | None = None, clearance: float = 0.02,
               margin: float = 0.9) -> Camera:
    """A camera at ``azimuth``/``elevation`` framing ``points``, kept above the ground.

    Parameters
    ----------
    points : (n, 3) float
        Geometry to frame (object and ice vertices), meters.
    gravity : (3,) float
        Gravity direction; up is its opposite.
    azimuth, elevation : float
        Where the camera sits, degrees (see `direction`).
    aspect : float
        Width over height.
    fov_y : float
        Vertical field of view, degrees.
    ground : float, optional
        Height (along up) of the ground plane; the camera is raised until its eye is
        ``clearance`` (a fraction of the scene size) above it.

    Returns
    -------
    Camera
    """
    frame = world_frame(gravity)
    up = frame[1]
    pts = framing_points(points)
    if len(pts) == 0:
        raise ValueError("nothing to frame: no points")
    fov_x = float(np.degrees(2 * np.arctan(np.tan(np.radians(fov_y) / 2) * aspect)))
    size = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0
    el = float(elevation)
    while True:
        origin, target = fit(pts, direction(frame, azimuth, el), up, fov_x, fov_y, margin)
        if ground is None or origin @ up >= ground + clearance * size or el >= 89.0:
            break
        el = min(el + 1.0, 89.0)
    dist = float(np.linalg.norm(target - origin))
    depth = (pts - origin) @ ((target - origin) / dist)
    near = max(float(depth.min()) * 0.5, 1e-4)
    return Camera(origin=origin, target=target, up=up, fov_x=fov_x, fov_y=float(fov_y),
                  near=near, far=max(1000.0 * dist, 100.0 * size))


# ------------------------------------------------------------------ the ice view
ICICLE_PX = 10.0  # icicle width (pixels) an ice view aims for (8 at least, with some slack)
MIN_ZOOM = 2.5  # an ice view is always a detail: at least this much closer than the full view
MAX_ZOOM = 40.0
FOCUS_SAMPLES = 12_000  # ice vertices looked at to find the icicles
SECTIONS = 12  # horizontal sections that find the icicles and measure their diameter
THIN = 2.5  # a section up to this times the median width is an icicle's, wider ones are lumps


@dataclass(frozen=True)
class IceFocus:
    """Where the ice is densest, for a view zoomed on it.

    Attributes
    ----------
    points : (n, 3) float
        Where the icicles are: the centres of their horizontal sections (or, when too
        few were found, sampled ice vertices away from the object; for glaze alone,
        sampled ice vertices).
    diameter : float or None
        Median icicle diameter (m) measured on horizontal sections; None without icicles.
    occluders : (m, 3) float
        Points of the object and the ice that may hide ``points`` from a camera.
    """

    points: np.ndarray
    diameter: float | None
    occluders: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def _edge_length(vertices: np.ndarray, faces: np.ndarray, count: int = 2000) -> float:
    """Median edge length (m) of up to ``count`` faces spread over the mesh."""
    step = max(1, len(faces) // count)
    tri = vertices[faces[::step]]
    return float(np.median(np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)))


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
    from scipy import ndimage

    right, _, front = frame
    widths, centres = [], []
    for k in np.unique(slab[slab >= 0]):
        q = points[slab == k]
        if len(q) < 4:
            continue
        xy = np.column_stack([q @ right, q @ front])
        ij = np.floor((xy - xy.min(axis=0)) / spacing).astype(np.int64)
        shape = ij.max(axis=0) + 1
        if shape[0] * shape[1] > 4_000_000:  # too wide a slab for a grid of that size
            continue
        grid = np.zeros(shape, dtype=bool)
        grid[ij[:, 0], ij[:, 1]] = True
        labels, _ = ndimage.label(ndimage.binary_dilation(grid, np.ones((3, 3), bool)))
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
              frame: np.ndarray, size: float) -> IceFocus | None:
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
        times the spacing of ``object_points``) from the object counts as icicles.

    Returns
    -------
    IceFocus or None
        None without ice.
    """
    from scipy.spatial import cKDTree

    vertices = np.asarray(ice_vertices, dtype=np.float64)
    if len(vertices) == 0:
        return None
    step = max(1, len(vertices) // FOCUS_SAMPLES)
    sample = vertices[::step]
    tree = cKDTree(object_points)
    gap = float(np.median(tree.query(object_points[:: max(1, len(object_points) // 2000)], k=2)[0][:, 1]))
    reach = max(0.02 * size, 3.0 * gap, 0.004)
    far = ~np.isfinite(tree.query(sample, distance_upper_bound=reach)[0])
    occluders = np.vstack([object_points, sample])
    if far.sum() < 20:  # glaze alone: the densest ice is anywhere on it
        return IceFocus(points=sample, diameter=None, occluders=occluders)
    icicles = sample[far]
    # Sections through every vertex of the icicles: thin slabs, then away from the object.
    up = frame[1]
    spacing = _edge_length(vertices, np.asarray(ice_faces))
    levels = slab_levels(icicles @ up)
    slab = in_slabs(vertices @ up, levels, spacing)
    lo, hi = icicles.min(axis=0) - reach, icicles.max(axis=0) + reach
    pick = np.flatnonzero(slab >= 0)
    pick = pick[np.all((vertices[pick] >= lo) & (vertices[pick] <= hi), axis=1)]
    pick = pick[~np.isfinite(tree.query(vertices[pick], distance_upper_bound=reach)[0])]
    widths, centres = section_diameters(vertices[pick], slab[pick], frame, spacing)
    if len(widths) == 0:
        return IceFocus(points=icicles, diameter=None, occluders=occluders)
    diameter = float(np.median(widths))
    thin = widths <= THIN * diameter  # icicles, not lumps of ice
    return IceFocus(points=centres[thin] if thin.sum() >= 3 else icicles, diameter=diameter,
                    occluders=occluders)


def visible(camera: Camera, points: np.ndarray, occluders: np.ndarray, width: int, height: int,
            tolerance: float, cell: int = 4) -> np.ndarray:
    """Which ``points`` no ``occluders`` hide from ``camera``: a z-buffer of the occluders.

    The occluders (surface points) are splatted into cells of ``cell`` pixels, each cell
    keeping the nearest depth; a point is hidden when it lies more than ``tolerance`` (m)
    behind its cell's depth. Cells no occluder reached hide nothing.
    """
    gw, gh = -(-width // cell), -(-height // cell)
    zbuf = np.full((gh, gw), np.inf)

    def cells(q):
        xy = camera.project(q, width, height)
        depth = (q - camera.origin) @ camera.forward
        ij = np.floor(xy / cell).astype(np.int64)
        ok = (depth > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < gw) & (ij[:, 1] >= 0) & (ij[:, 1] < gh)
        return ij, depth, ok

    ij, depth, ok = cells(np.asarray(occluders, dtype=np.float64).reshape(-1, 3))
    np.minimum.at(zbuf, (ij[ok, 1], ij[ok, 0]), depth[ok])
    ij, depth, ok = cells(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    out = np.zeros(len(depth), dtype=bool)
    out[ok] = depth[ok] <= zbuf[ij[ok, 1], ij[ok, 0]] + tolerance
    return out


def pixel_size(camera: Camera, point: np.ndarray, width: int) -> float:
    """Meters per pixel at ``point`` for ``camera`` rendering ``width`` pixels across."""
    depth = float((np.asarray(point) - camera.origin) @ camera.forward)
    return 2.0 * max(depth, 1e-9) * np.tan(np.radians(camera.fov_x) / 2) / width


def zoom_on_ice(full: Camera, focus: IceFocus, width: int, height: int) -> Camera:
    """A camera at ``full``'s position turned and zoomed onto the densest icicles.

    The zoom makes icicles of ``focus.diameter`` about `ICICLE_PX` pixels wide (at least
    `MIN_ZOOM`, at most `MAX_ZOOM` times closer than ``full``); the window of the full
    picture it then shows is placed where it holds the most icicle points.
    """
    pixels = full.project(focus.points, width, height)
    ahead = ((focus.points - full.origin) @ full.forward) > 0
    inside = ahead & (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
    if len(focus.occluders):  # icicles the camera sees, not those behind the object
        span = np.ptp(focus.occluders, axis=0).max() if len(focus.occluders) > 1 else 0.0
        tolerance = max(2.0 * (focus.diameter or 0.0), 0.01 * span)
        seen = inside & visible(full, focus.points, focus.occluders, width, height, tolerance)
        if seen.any():
            inside = seen
    if not inside.any():
        return full
    pixels, points = pixels[inside], focus.points[inside]
    zoom = MIN_ZOOM
    if focus.diameter:
        centre = np.median(points, axis=0)
        seen = focus.diameter / pixel_size(full, centre, width)
        zoom = max(MIN_ZOOM, ICICLE_PX / max(seen, 1e-9))
    zoom = min(zoom, MAX_ZOOM)
    # Densest window: counts in bins a quarter of the window, summed over 4 x 4 bins.
    win = np.array([width, height]) / zoom
    bins = win / 4
    ij = np.floor(pixels / bins).astype(np.int64)
    shape = ij.max(axis=0) + 1
    counts = np.zeros(shape + 1)
    np.add.at(counts, (ij[:, 0] + 1, ij[:, 1] + 1), 1)
    cum = counts.cumsum(0).cumsum(1)
    k = 4
    a, b = min(k, shape[0]), min(k, shape[1])
    sums = cum[a:, b:] - cum[:-a, b:] - cum[a:, :-b] + cum[:-a, :-b]
    i, j = np.unravel_index(np.argmax(sums), sums.shape)
    sel = (ij[:, 0] >= i) & (ij[:, 0] < i + a) & (ij[:, 1] >= j) & (ij[:, 1] < j + b)
    # Aim at the middle of the icicle points in that window (their median: on the
    # icicles that gather most there, the others at its edges).
    cx, cy = np.median(pixels[sel], axis=0)
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
