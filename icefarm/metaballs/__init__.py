"""A domain-free mesher for Gaussian metaballs: sparse field, marching cubes, fusion.

It knows nothing of icicles: balls in, one watertight mesh in meters out.
"""

from __future__ import annotations

from .balls import KAPPA, LEVEL, NO_BALLS, SPACING, Balls, concat_balls, sheet_balls
from .field import Field, sample_field
from .fuse import fuse_fields, union_meshes
from .march import polygonize

__all__ = ["KAPPA", "LEVEL", "NO_BALLS", "SPACING", "Balls", "Field", "concat_balls", "fuse_fields",
           "polygonize", "sample_field", "sheet_balls", "union_meshes"]
