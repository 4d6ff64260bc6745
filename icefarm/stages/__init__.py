"""The stages of a job (paper 4.1-4.4 and 5.1): pure functions of meshes, arrays and parameters.

`proxy` (the approximate surface stages 1-2 run on, 5.1) with `proxy_checks` (why a mesh
needs one, and snapping points back onto the object), `storm` (the weather in physical
units), `water` (stage 1), `drips` (stage 2), `rims`, `icicle_size`, `trajectories` (stage 3)
with `turtles` and `trajectory_stats`, `landing` (where the water off the tips lands),
`surface` (stage 4) and `growth` (the inputs of stage 4 at a fraction of the growth).

The package's face: the names the rest of icefarm imports from it, listed in `__all__` and
loaded on first use (`lazy_loader`, as scikit-image does), so that importing one module of
the package imports no other.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "drips": ["DripOptions", "DripResult", "DripStorm", "find_drips"],
    "growth": ["MAX_FRAMES", "frame_fractions", "noise_draws", "stage4_inputs_at", "trajectories_at"],
    "icicle_size": ["BRANCH_LIFE", "IcicleGrowth", "IcicleSizing", "grow_icicles", "growth_ratios", "icicle_lengths",
                    "thickening_m"],
    "landing": ["LandingOptions", "find_landings"],
    "proxy": ["ProxyMethod", "build_proxy"],
    "proxy_checks": ["proxy_reason", "snap_to_surface"],
    "storm": ["StormOptions", "constants", "drip_rim_length", "precipitation_m", "refine", "storm_water"],
    "surface": ["SLIVER", "CoatSurface", "GlazeProbe", "IceInputs", "build_ice", "carry_water", "fringe_figures",
                "ground_ice_balls", "icicle_balls", "measure_glaze", "measure_icicles", "meshing_view", "profile_args",
                "ripple_bands", "view_surface", "VIEW_PX"],
    "trajectories": ["TrajectoryOptions", "TrajectoryResult", "grow_trajectories", "trajectory_options"],
    "trajectory_stats": ["measure_trajectories"],
    "water": ["RainOptions", "WaterResult", "compute_water"],
})
