"""Stage 4 (paper 4.4): the ice surface, icicles, their bases and glaze ice as one watertight mesh.

Every icicle branch becomes a chain of metaballs whose radii follow the profile of
Equation 1; metaballs around each drip point form the base (Equation 2) and metaballs
over the wet surface form the glaze (Equation 3). The icicle and base balls add into ONE
field, so branches fuse with their trunk and touching icicles fuse with each other, and
the iso-surface of that field is polygonised by marching cubes into one mesh in meters.
The glaze covers the whole wet surface, so at the voxel the tip radius needs it would
dominate the mesh: its balls get a field of their own on the coarser ``glaze.voxel_size``
lattice, and the two closed surfaces are joined by a boolean union (manifold3d), run only
where they come close (`fuse_fields`). With ``glaze.voxel_size <= surface.voxel_size``
the glaze joins the one field instead, and fuses smoothly with the bases.

The metaballs are Gaussian (Blinn's blobby model): the one kernel that is both radial
and separable. Separability turns the field of a block of ``B^3`` samples into a matrix
product over the balls touching that block, so evaluation runs in BLAS, and only in the
blocks that balls reach (a sparse block grid: memory and time follow the ice, not its
bounding box). Each sample is computed once, by the block that owns it; a block marches
its cells with its upper neighbours' first samples as a halo, so blocks can never
disagree on a shared sample and the mesh closes across seams. Calibration (`icefarm.metaballs.balls`):

* chain of balls of radius R: width ``s = KAPPA * R``, spacing ``SPACING * s``; the
  line integral ``(sqrt(pi) s / h) exp(-rho^2 / s^2)`` of a dense chain equals
  ``LEVEL`` at ``rho = R`` exactly, so a straight chain's surface sits at R
  (bumps between balls stay below 0.1 % of R); the last ball of a branch weighs
  ``TIP_WEIGHT`` so the end of the chain is a hemisphere of radius R(L) (within 2 %);
* base and glaze balls of radius r, one per area A of the surface: width
  ``max(SHEET_KAPPA * r, SHEET_OVERLAP * sqrt(A))`` and a weight that makes the sheet
  they form r thick on each side of the surface (a plane of balls integrates to
  ``pi s^2 / A exp(-z^2 / s^2)``), so Equations 2 and 3 give ice thickness.

``surface.mode == "tubes"`` (the paper's future work, 6.1) sweeps each branch as a
closed tube with the same profile instead: instant, no fusion, no base, no glaze.
"""

from __future__ import annotations

from .build import IceResult, build_ice
from .profile import TIP_CALM, profile_radius

__all__ = ["IceResult", "TIP_CALM", "build_ice", "profile_radius"]
