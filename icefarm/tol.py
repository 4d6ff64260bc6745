"""Tolerances in one place, after trimesh's ``trimesh.tol``.

``tol`` holds three kinds, each field's docstring saying which:

- fractions of an object's size, its bounding-box diagonal ``norm(mesh.extents)`` (or its
  largest extent where the docstring says so): a caller multiplies by that size in meters,
  so a 10 cm teapot and a 3 m house are treated alike;
- meters: offsets of rays cast from a surface, well above Embree's float32 noise (1e-4 m is
  about 100 ulps at 10 m);
- plain numbers: the float slack of comparing ratios, or vectors of unit scale.

Changing a value changes meshes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """The package's tolerances; use the instance `tol`."""

    # Fractions of the bounding-box diagonal.
    flat: float = 1e-6
    """A mesh thinner than this fraction of its diagonal is flat: no volume to wrap, no
    inside."""
    on_surface: float = 1e-9
    """A point within this fraction of the diagonal of a surface lies on it (which side it
    came from is rounding noise)."""
    offset: float = 1e-4
    """Points start this fraction of the diagonal off a face along its normal: a drip point
    tested for lying inside another part, a turtle leaving the surface (and the slack of its
    collisions)."""
    hair: float = 1e-5
    """Rays from a vertex start this fraction of the diagonal off it (along its normal, and
    against gravity for rays up), so that they miss the faces around it."""
    drop: float = 1e-7
    """An edge whose ends differ in height by more than this fraction of the diagonal runs
    downhill (the storm's flow)."""

    # Fractions of the largest extent.
    level: float = 1e-6
    """Heights within this fraction of the largest extent are one level (the lowest
    outlets, the water standing above a vertex)."""
    inset: float = 1e-6
    """A ray measuring a part's thickness starts this fraction of the largest extent inside
    it."""

    # Meters.
    ray_lift_m: float = 1e-4
    """Rays from a point on a surface start this far off it (along its normal or against
    gravity), so that they do not hit the face they start on."""
    ray_under_m: float = 2e-4
    """A ray measuring a coat's thickness along the normal starts this far under the
    surface: inside a coat whose inner side lies inside the object."""
    ray_past_m: float = 1e-6
    """A ray measuring a coat is cast again from this far past the face where it entered."""
    parity_step_m: float = 1e-7
    """Counting crossings (`icefarm.spatial.inside`), each ray is cast again from this far
    past every hit."""

    # Plain numbers.
    degenerate: float = 1e-12
    """Faces lower than this (trimesh's ``nondegenerate_faces(height=...)``, in the mesh's
    own units) are degenerate."""
    zero: float = 1e-9
    """A vector of unit scale shorter than this has no direction of its own (a fallback
    direction takes over)."""
    slack: float = 1e-9
    """Relative float slack: a ratio within this of an integer or of a bound reaches it."""


tol = Tolerances()
