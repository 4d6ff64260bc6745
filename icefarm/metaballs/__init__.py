"""A domain-free mesher for Gaussian metaballs: sparse field, marching cubes, fusion.

It knows nothing of icicles: balls in, one watertight mesh in meters out.
"""

from __future__ import annotations

from .balls import KAPPA, LEVEL, NO_BALLS, SPACING, TIP_WEIGHT, Balls, concat_balls, sheet_balls
from .clean import clean_slivers, collapse_slivers, flip_needles, sliver_candidates
from .field import BLOCK, CUTOFF, Field, block_keys, sample_field, values_at
from .fuse import fuse_fields, union_meshes
from .march import face_estimate, march_blocks, polygonize
from .march_kernel import MARCH_POWER

__all__ = ["BLOCK", "CUTOFF", "KAPPA", "LEVEL", "MARCH_POWER", "NO_BALLS", "SPACING", "TIP_WEIGHT", "Balls",
           "Field", "block_keys", "clean_slivers", "collapse_slivers", "concat_balls", "face_estimate",
           "flip_needles", "fuse_fields", "march_blocks", "polygonize", "sample_field", "sheet_balls",
           "sliver_candidates", "union_meshes", "values_at"]
