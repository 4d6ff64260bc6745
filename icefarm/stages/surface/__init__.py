"""Stage 4 (paper 4.4): icicles, their bases and glaze ice as one watertight mesh.

Every icicle branch becomes a chain of metaballs whose radii follow the smooth profile
(`profile`: ``physical`` r = tip + t L^1/4 d^3/4, or the paper's Equation 1 cone); balls
around each drip point swell its base (`bases`, Equation 2); sheets join close trunks
(`curtains`) and mounds and stalagmites grow where the water off the tips lands
(`ground_ice`, beyond the paper). They add into one field at ``surface.voxel_size``, so
branches fuse with their trunk, touching icicles fuse and a stalagmite that meets its
icicle becomes a column. The glaze (`glaze`, Equation 3) is a continuous coat (`coat`: a
signed-distance field over the wet surface) or the paper's balls, on the coarser
``glaze.voxel_size`` lattice; the two are joined where they meet by
`icefarm.metaballs.fuse_fields`. Ripples are then carved into the mesh (`ripples`: a chain
of balls blurs them away), slivers are cleaned (`icefarm.metaballs.clean`) and the icicles
measured (`measure`; the fringe as a whole in `fringe`). The mesher itself (field, marching cubes, fusion,
calibration) is `icefarm.metaballs`.

``surface.mode == "tubes"`` (the paper's future work, 6.1) sweeps each branch as a
closed tube with the same profile instead: instant, no fusion, no base, no glaze.
"""

from __future__ import annotations

from .build import SLIVER, IceInputs, IceResult, build_ice
from .detail import VIEW_PX, meshing_view, view_surface
from .fringe import FringeFigures, fringe_figures
from .glaze import CoatSurface, carry_water
from .glaze_measure import GlazeProbe, measure_glaze
from .ground_ice import ground_ice_balls
from .icicles import icicle_balls
from .measure import measure_icicles
from .profile import TIP_CALM, Profile, profile_args, profile_radius, smooth_radius
from .ripples import ripple_bands

__all__ = ["SLIVER", "CoatSurface", "FringeFigures", "GlazeProbe", "IceInputs", "IceResult", "Profile",
           "fringe_figures", "TIP_CALM",
           "build_ice", "carry_water", "ground_ice_balls", "icicle_balls", "measure_glaze", "measure_icicles",
           "profile_args", "profile_radius", "ripple_bands", "smooth_radius", "VIEW_PX", "meshing_view", "view_surface"]
