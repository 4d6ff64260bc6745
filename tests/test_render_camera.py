"""Cameras: framing along gravity, and the ice view that zooms on the icicles."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from icefarm.scene.camera import frame_view, world_frame
from icefarm.scene.config import load_render_config, render_config_from_dict
from icefarm.scene.write import JobScene, write_scenes


@pytest.mark.parametrize("gravity", [(0, -1, 0), (0, 0, -1), (1, 0, 0)])
def test_camera_up_follows_gravity_and_frames_everything(gravity, box_with_icicles):
    box, ice = box_with_icicles(gravity)
    points = np.vstack([box.vertices, ice.vertices])
    up = world_frame(gravity)[1]
    assert np.allclose(up, -np.asarray(gravity, float))
    ground = float((points @ up).min())
    camera = frame_view(points, gravity, 35.0, -8.0, 4 / 3, ground=ground)
    assert np.allclose(camera.up, up)
    assert camera.origin @ up > ground
    pixels = camera.project(points, 400, 300)
    assert (pixels >= 0).all() and (pixels[:, 0] <= 400).all() and (pixels[:, 1] <= 300).all()
    assert np.ptp(pixels[:, 0]) > 0.8 * 400 or np.ptp(pixels[:, 1]) > 0.8 * 300  # fills the frame
    # Hanging icicles (along gravity) go down the picture.
    tip, root = camera.project(np.array([[0, 0, 0], [0, 0, 0]]) + [up * -0.1, up * 0.0], 400, 300)
    assert tip[1] > root[1]


def test_the_ground_in_the_frame_lies_past_the_near_plane():
    """A long, low asset (a 4.5 m car shape) seen from slightly below (the three-quarter view): the
    eye sits just over the ground, whose nearest visible metres the near plane, set from the
    asset alone, clipped (a flat dark band across the frame's foot)."""
    car = trimesh.creation.box(extents=(4.5, 1.5, 1.8))
    car.apply_translation((0.0, 0.75, 0.0))
    gravity = np.array([0.0, -1.0, 0.0])
    camera = frame_view(car.vertices, gravity, 35.0, -8.0, 4 / 3, ground=0.0)  # three_quarter
    fwd = (camera.target - camera.origin) / np.linalg.norm(camera.target - camera.origin)
    # the ground point seen at the middle of the frame's lower edge, and its depth along fwd
    right = np.cross(fwd, camera.up)
    right /= np.linalg.norm(right)
    low = fwd - np.tan(np.radians(camera.fov_y) / 2) * np.cross(right, fwd)
    assert low[1] < 0  # the frame's foot shows ground
    depth = camera.origin[1] / -low[1]
    assert depth < np.linalg.norm(camera.target - camera.origin)  # nearer than the asset
    assert camera.near < depth
    # the asset itself stays past the near plane too
    assert ((car.vertices - camera.origin) @ fwd).min() > camera.near


def dense_icicles(count: int = 5, spacing: float = 0.05):
    """A 30 cm box with ``count`` cones hanging from its underside, finely meshed like the
    pipeline's marching-cubes ice (edges of about 1.5 mm: split until none is over 3 mm),
    12 mm radius at the root."""
    box = trimesh.creation.box(extents=(0.3, 0.1, 0.2))
    box.apply_translation((0.0, 0.05, 0.0))
    cones = []
    for i in range(count):
        cone = trimesh.creation.cone(radius=0.012, height=0.08 + 0.02 * (i % 3), sections=48)
        cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # tip -Y
        cone.apply_translation(((i - (count - 1) / 2) * spacing, 0.0, 0.04))
        cones.append(cone)
    ice = trimesh.util.concatenate(cones)
    v, f = trimesh.remesh.subdivide_to_size(ice.vertices, ice.faces, max_edge=0.003)
    return box, trimesh.Trimesh(v, f, process=False), cones


@pytest.fixture(scope="module")
def dense():
    """`dense_icicles()` once for the module: its fine meshing is most of a test's time."""
    return dense_icicles()


def cone_widths(camera, cones, width, height):
    """Width in pixels of each cone halfway down, and whether that point is in the frame."""
    right = np.cross(camera.forward, camera.up)
    right /= np.linalg.norm(right)
    out = []
    for cone in cones:
        lo, hi = cone.bounds
        mid = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])
        radius = 0.012 * 0.5  # halfway down the cone
        a, b = camera.project(np.array([mid - radius * right, mid + radius * right]), width, height)
        centre = camera.project(mid[None], width, height)[0]
        inside = 0 <= centre[0] < width and 0 <= centre[1] < height
        out.append((float(np.linalg.norm(a - b)), inside))
    return out


def test_lookdev_has_an_ice_view_that_frames_the_icicles(tmp_path, dense):
    import json

    lookdev = load_render_config("lookdev")
    assert [v.frame for v in lookdev.views] == ["all", "ice"]
    config = render_config_from_dict({"resolution": [160, 120]}, base=lookdev)
    box, ice, cones = dense
    files = write_scenes(tmp_path, JobScene(box, ice), config)
    full, zoomed = files.cameras
    assert np.allclose(full.origin, zoomed.origin) and zoomed.fov_x < full.fov_x / 2
    seen_full = cone_widths(full, cones, 160, 120)
    seen_ice = cone_widths(zoomed, cones, 160, 120)
    assert all(inside for _, inside in seen_full) and max(w for w, _ in seen_full) < 8
    in_frame = [w for w, inside in seen_ice if inside]
    assert in_frame and min(in_frame) >= 8  # every icicle it shows is at least 8 px wide
    views = json.loads((tmp_path / "views.json").read_text())
    assert [(v["name"], v["frame"], v["stem"]) for v in views] == [
        ("three_quarter", "all", "render"), ("ice", "ice", "render_view1")]
    assert views[0]["icicle_px"] < 8 and views[1]["icicle_px"] >= 12  # the ice view: icicles 12 px wide at least
    assert files.icicle_px == (views[0]["icicle_px"], views[1]["icicle_px"])
    # Both renderers get the zoomed camera.
    assert f"{zoomed.fov_x:.9g}" in files.xml.read_text() and f"angle {zoomed.fov_x:.9g}" in files.pov.read_text()


def test_ice_view_without_ice_or_icicles_still_renders_a_view(tmp_path, dense):
    import json

    config = render_config_from_dict({"resolution": [64, 48]}, base=load_render_config("lookdev"))
    box, _, _ = dense
    files = write_scenes(tmp_path / "bare", JobScene(box, None), config)
    assert len(files.cameras) == 2 and np.allclose(files.cameras[0].origin, files.cameras[1].origin)
    assert [v["icicle_px"] for v in json.loads((tmp_path / "bare" / "views.json").read_text())] == [None, None]
    glaze = box.copy()
    glaze.vertices *= 1.02  # a thin shell: ice, but no icicles
    files = write_scenes(tmp_path / "glaze", JobScene(box, glaze), config)
    assert files.cameras[1].fov_x < files.cameras[0].fov_x


def test_an_ice_view_shows_its_icicles_whole_when_sections_find_only_their_tips():
    """Sections through icicles can lie at their tips only (a lamp's: thick merged tops are
    left out as lumps); the view then still frames them from where they hang to their tips,
    with icicles at least 12 px wide; and a curtain too long for that shows its tips."""
    from icefarm.scene.camera import Camera
    from icefarm.scene.focus import IceFocus, zoom_on_ice

    width, height = 160, 120
    full = Camera(origin=np.array([0.0, -0.2, 1.5]), target=np.array([0.0, -0.05, 0.0]), up=np.array([0.0, 1.0, 0.0]),
                  fov_x=30.0, fov_y=22.5, near=0.01, far=100.0)

    def icicles(length):
        xs = np.array([-0.05, 0.0, 0.05])
        t = np.linspace(0.0, 1.0, 60)
        ring = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        radius = 0.012 * (1 - t)[:, None]  # cones hanging from y = 0, 12 mm radius at the root
        surface = np.array([[x + r * np.cos(a), -length * tt, r * np.sin(a)]
                            for x in xs for tt, rr in zip(t, radius) for r in rr for a in ring])
        tips = np.array([[x, -length * tt, 0.0] for x in xs for tt in (0.8, 0.85, 0.9)])
        return IceFocus(points=tips, diameter=0.012, icicles=surface, clearance=0.01), xs

    for length, whole in ((0.08, True), (0.4, False)):
        focus, xs = icicles(length)
        cam = zoom_on_ice(full, focus, width, height)
        seen = 0.012 / (2 * np.linalg.norm(cam.target - cam.origin) * np.tan(np.radians(cam.fov_x) / 2) / width)
        assert seen >= 12.0
        tips = cam.project(np.c_[xs, np.full(3, -length), np.zeros(3)], width, height)
        roots = cam.project(np.c_[xs, np.zeros(3), np.zeros(3)], width, height)
        framed = (tips[:, 0] >= 0) & (tips[:, 0] < width)
        assert framed.any()
        assert (tips[framed, 1] < height).all()  # the tips are in the frame
        assert (roots[framed, 1] >= 0).all() == whole  # and so are the roots, where they fit


def test_the_ice_view_tells_icicles_from_glaze_thicker_than_its_reach(dense):
    """Glaze 4 cm thick on the box's top lies farther from the object than the 9 mm that tells
    icicles from glaze (2 % of the scene): given the icicles' axes, the ice view's icicles are
    the cones under the box, not the glaze (a 0.3 m bunny's 2 cm glaze on its back was framed
    over the icicles under its chin)."""
    from icefarm.scene.camera import world_frame
    from icefarm.scene.focus import ice_focus, surface_points

    box, cones_mesh, cones = dense
    slab = trimesh.creation.box(extents=(0.3, 0.04, 0.2))
    slab.apply_translation((0.0, 0.12, 0.0))
    v, f = trimesh.remesh.subdivide_to_size(slab.vertices, slab.faces, max_edge=0.003)
    ice = trimesh.util.concatenate([cones_mesh, trimesh.Trimesh(v, f, process=False)])
    axes = np.vstack([np.c_[np.full(20, c.bounds.mean(axis=0)[0]), np.linspace(0.0, c.bounds[0][1], 20),
                            np.full(20, 0.04)] for c in cones])
    frame = world_frame((0, -1, 0))
    size = float(np.linalg.norm(np.ptp(np.vstack([box.vertices, ice.vertices]), axis=0)))
    blind = ice_focus(ice.vertices, ice.faces, surface_points(box), frame, size)
    assert (blind.icicles[:, 1] > 0.1).any()  # without the axes the glaze counts as icicles
    focus = ice_focus(ice.vertices, ice.faces, surface_points(box), frame, size, axes=axes)
    assert len(focus.icicles) > 100 and (focus.icicles[:, 1] < 0.0).all()
    assert (focus.points[:, 1] < 0.0).all() and focus.diameter < 0.03


def test_the_ice_view_does_not_depend_on_the_order_of_the_ice_vertices(dense):
    """The same ice, its vertices and faces in another order (as marching cubes' batches
    give them), finds the same icicles: every so-many vertices in memory order moved the
    0.4 m fountain's ice view 35 cm along its rim."""
    from icefarm.scene.camera import world_frame
    from icefarm.scene.focus import FOCUS_SAMPLES, ice_focus, surface_points

    box, cones_mesh, _ = dense
    ice = cones_mesh.copy()
    v, f = trimesh.remesh.subdivide(ice.vertices, ice.faces)  # more vertices than FOCUS_SAMPLES
    v, f = trimesh.remesh.subdivide(v, f)
    assert len(v) > 2 * FOCUS_SAMPLES
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(v))
    moved_v = np.empty_like(v)
    moved_v[perm] = v
    moved_f = perm[f][rng.permutation(len(f))]
    frame = world_frame((0, -1, 0))
    size = float(np.linalg.norm(np.ptp(np.vstack([box.vertices, v]), axis=0)))
    a = ice_focus(v, f, surface_points(box), frame, size)
    b = ice_focus(moved_v, moved_f, surface_points(box), frame, size)
    assert a.diameter == pytest.approx(b.diameter, rel=1e-12)
    assert np.array_equal(a.icicles, b.icicles)
    np.testing.assert_allclose(np.sort(a.points, axis=0), np.sort(b.points, axis=0), rtol=0, atol=1e-12)


def test_the_ice_view_stays_put_when_only_the_ice_surface_changes(dense):
    """Given the icicles' axes, the ice view is framed from them: ripples 0.5 mm deep carved
    into the same icicles (a change of impurity) leave its aim where it was. Framed from
    the sections through the mesh, a change to the ripples turned a car's ice view 16.5
    degrees, onto other icicles."""
    from icefarm.scene.camera import Camera, world_frame
    from icefarm.scene.focus import ice_focus, surface_points, zoom_on_ice

    box, cones_mesh, cones = dense
    axes = np.vstack([np.c_[np.full(20, c.bounds.mean(axis=0)[0]), np.linspace(0.0, c.bounds[0][1], 20),
                            np.full(20, 0.04)] for c in cones])
    v = cones_mesh.vertices
    centre = np.array([[c.bounds.mean(axis=0)[0], 0.0, 0.04] for c in cones])
    own = np.argmin(np.abs(v[:, None, 0] - centre[None, :, 0]), axis=1)
    radial = v - centre[own]
    radial[:, 1] = 0.0
    phase = np.random.default_rng(1).random(len(cones))[own, None] * 2 * np.pi  # each icicle its own
    rippled = v + 0.0005 * np.sin(2 * np.pi * v[:, 1:2] / 0.01 + phase) * radial / np.maximum(
        np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    frame = world_frame((0, -1, 0))
    size = float(np.linalg.norm(np.ptp(np.vstack([box.vertices, v]), axis=0)))
    full = Camera(origin=np.array([0.5, 0.2, 0.8]), target=np.array([0.0, -0.05, 0.0]), up=np.array([0.0, 1.0, 0.0]),
                  fov_x=40.0, fov_y=30.0, near=0.01, far=100.0)
    views = []
    for verts in (v, rippled):
        focus = ice_focus(verts, cones_mesh.faces, surface_points(box), frame, size, axes=axes)
        views.append((focus, zoom_on_ice(full, focus, 160, 120)))
    (a, view_a), (b, view_b) = views
    assert np.array_equal(a.points, b.points) and len(a.points) >= 3
    assert np.degrees(np.arccos(np.clip(view_a.forward @ view_b.forward, -1, 1))) < 0.5
    assert view_b.fov_x == pytest.approx(view_a.fov_x, rel=0.1)


def test_the_ice_view_frames_icicles_the_object_does_not_hide():
    """A car's densest icicles hung behind its front wheel, and the ice view framed the wheel.
    Rays cast against the object tell hidden icicles from seen ones: a wall in front of the
    denser of two clusters sends the view to the other, and none of its icicles is hidden."""
    from icefarm.scene.camera import Camera
    from icefarm.scene.focus import IceFocus, visible, zoom_on_ice
    from icefarm.spatial import ray_caster

    width, height = 160, 120
    full = Camera(origin=np.array([0.0, 0.0, 2.0]), target=np.zeros(3), up=np.array([0.0, 1.0, 0.0]),
                  fov_x=40.0, fov_y=30.0, near=0.01, far=100.0)

    def cluster(x0, count):  # section centres down `count` icicles 3 cm apart
        xs = x0 + 0.03 * np.arange(count)
        return np.array([[x, y, 0.0] for x in xs for y in np.linspace(-0.02, -0.12, 6)])

    dense, sparse = cluster(-0.35, 8), cluster(0.2, 4)
    focus = IceFocus(points=np.vstack([dense, sparse]), diameter=0.012)
    wall = trimesh.creation.box(extents=(0.3, 0.3, 0.02))
    wall.apply_translation((-0.25, -0.07, 0.3))  # between the camera and the dense cluster
    cast = ray_caster(wall)
    assert not visible(full, dense, cast, 0.01).any() and visible(full, sparse, cast, 0.01).all()

    def aimed(cam):  # the cluster nearest the view's line of sight
        ray = (cam.target - cam.origin) / np.linalg.norm(cam.target - cam.origin)
        miss = [np.linalg.norm(np.cross(c.mean(axis=0) - cam.origin, ray)) for c in (dense, sparse)]
        return int(np.argmin(miss))

    assert aimed(zoom_on_ice(full, focus, width, height)) == 0  # blind to the wall: the denser one
    cam = zoom_on_ice(full, focus, width, height, cast)
    assert aimed(cam) == 1
    px = cam.project(sparse, width, height)
    framed = (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
    assert framed.any() and visible(cam, sparse[framed], cast, 0.01).all()


def test_the_sections_grid_is_dilated_as_ndimage_dilates_it():
    from scipy import ndimage

    from icefarm.scene.focus import dilated

    rng = np.random.default_rng(2)
    for shape in ((200, 300), (1, 5), (5, 1), (1, 1)):
        grid = rng.random(shape) < 0.05
        grid[0, -1] = True  # a corner: the border stays outside
        assert np.array_equal(dilated(grid), ndimage.binary_dilation(grid, np.ones((3, 3), bool)))
