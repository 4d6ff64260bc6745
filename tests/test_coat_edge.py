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
