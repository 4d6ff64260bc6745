"""Where the glaze coat ends past the rim of the wet surface: it stops at a small step instead of
thinning to a sheet that grazes the object (whose line of contact rendered as black cracks)."""

from __future__ import annotations

import numpy as np
import trimesh


def test_the_coat_never_grazes_the_object_past_its_rim(surface_kit):
    radius = 0.15
    obj = surface_kit.sphere(radius)
    wet = obj.vertices[:, 1] > 0.02  # the top cap: its rim runs around the sphere
    surface, glaze = surface_kit.groups()
    ice = surface_kit.ice(obj, surface_kit.water(obj, wet), surface_kit.drips(obj, []), surface_kit.no_icicles(),
                          surface, glaze)
    mesh = trimesh.Trimesh(ice.vertices, ice.faces, process=False)
    centre = mesh.triangles_center
    height = np.linalg.norm(centre, axis=1) - radius
    outward = np.abs(np.einsum("ij,ij->i", mesh.face_normals, centre / np.linalg.norm(centre, axis=1)[:, None]))
    above = height > 0
    # Faces lying along the sphere less than a tenth of a voxel above it: a sheet thinner than
    # a ray's offset. Thinning to nothing past the rim gave 6 % of the coat's outer area here.
    grazing = above & (height < 0.1 * glaze.voxel_size) & (outward > 0.9)
    share = mesh.area_faces[grazing].sum() / mesh.area_faces[above & (outward > 0.9)].sum()
    assert share < 0.015, f"{share:.1%} of the coat grazes the object"
    # The taper is still there: the coat thins past the rim down to its end (`TAPER_END`).
    rim_side = above & (np.abs(centre[:, 1] - 0.02) < 0.01)
    assert rim_side.any() and height[rim_side].min() < 0.5 * np.median(height[above & (centre[:, 1] > 0.08)])



def _strip_post(half, strips):
    """A square post along z (half extents ``half``), its +x face cut into long strips
    ``strips`` (m) in from its +y edge, as a refined box-modelled asset's faces are."""
    h = half[0]
    ring = np.array([(-h, -h), (h, -h)] + [(h, h - s) for s in sorted(strips, reverse=True)] + [(h, h), (-h, h)])
    n = len(ring)
    verts = np.concatenate([np.c_[ring, np.full(n, -half[2])], np.c_[ring, np.full(n, half[2])]])
    i = np.arange(n)
    j = (i + 1) % n
    fan = np.c_[np.zeros(n - 2, int), np.arange(1, n - 1), np.arange(2, n)]
    post = trimesh.Trimesh(verts, np.concatenate([np.c_[i, j, j + n], np.c_[i, j + n, i + n], fan[:, ::-1], fan + n]))
    trimesh.repair.fix_normals(post)
    assert post.is_watertight and post.volume > 0
    return post


def test_a_rivulet_down_a_sharp_edge_gets_a_coat_as_thin_as_its_ice():
    """A rivulet runs down the +x face of a square post along its +y edge, on thin strips
    of faces (1.2 mm of ice), and the +y face beside it is dry: the coat hugs the post. The
    planes of the strips' samples ran on past the edge, and the coat's hidden inner part
    with them: fins and spikes stood 12 mm off this post, and off a fence's picket edges."""
    from icefarm.metaballs import fuse_fields
    from icefarm.stages.surface.coat import CoatOptions, coat_field

    half = np.array([0.04, 0.04, 0.15])
    post = _strip_post(half, [0.003, 0.0015, 0.0009, 0.0006, 0.0003])
    v = post.vertices
    wet = np.isclose(v[:, 0], half[0]) & (v[:, 1] >= half[1] - 0.0016)
    voxel = 0.004
    verts, faces = fuse_fields(None, coat_field(post, np.where(wet, 0.0012, 0.0), wet, CoatOptions(voxel, edge=0.01)))
    assert trimesh.Trimesh(verts, faces, process=False).is_watertight
    q = np.abs(verts) - half
    out = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    # Never past its thickness but for marching's error (the coat's signed distance is
    # exact on the faces, and round past the edge: the largest of the two faces' planes), and
    # there all along the rivulet. With the faces' planes alone (the edge's offset, no plane
    # across) it stood 1.54 mm off the post at the end of the rivulet.
    assert out.max() <= 0.0012 + 0.05 * voxel, f"the coat stands {out.max() * 1000:.2f} mm off the post"
    along = (verts[:, 0] > half[0]) & (np.abs(verts[:, 2]) < 0.1)
    assert np.ptp(verts[along, 2]) > 0.19 and np.median(out[along]) > 0.0008
