"""One frozen dataclass per parameter group, written out so that type checkers and editors
see each field: the registry (`icefarm.param_table`) holds their domains, defaults and docs
(``icefarm params`` lists them), `icefarm.params.resolve` validates and builds them.

Fields follow the registry's order with its kinds' Python types (vectors are 3-tuples); a
test holds them equal to it. Comments give the registry's unit, or a choice's values.
"""

# No ``from __future__ import annotations``: the fields' types stay classes, which the test
# against the registry compares.
from dataclasses import dataclass

__all__ = ["DripsParams", "GlazeParams", "GroundIceParams", "GrowthParams", "ProxyParams", "StormParams",
           "SurfaceParams", "TrajectoriesParams", "WaterParams"]


@dataclass(frozen=True)
class StormParams:
    """The storm in physical units (`icefarm.stages.storm`): what makes the water, glaze and icicles."""

    mode: str  # physical | relative
    kind: str  # freezing_rain | meltwater
    intensity: str  # light | moderate | severe
    precipitation: float  # mm of water; 0: the intensity's
    freeze: float  # share of the rain on a level face
    wall_freeze: float  # share of a level face's budget
    wind: tuple[float, float, float]  # m/s
    max_icicles: int
    flow_edge: float  # m


@dataclass(frozen=True)
class WaterParams:
    """Stage 1, the water coefficients (paper 4.1)."""

    source: str  # "auto" or a mesh file
    gravity: tuple[float, float, float]  # unit vector once resolved
    rays: int
    influence_radius: float  # m
    pools: str  # ignore | overflow


@dataclass(frozen=True)
class DripsParams:
    """Stage 2, the drip points (paper 4.2)."""

    count: int
    drip_limit: float  # deg
    spacing: float  # m
    min_fall: float  # m
    min_length: float  # m
    distribution: str  # water | area
    ground_clearance: float  # share of the object's height


@dataclass(frozen=True)
class TrajectoriesParams:
    """Stage 3, the icicles' trajectories (paper 4.3)."""

    curve_angle: float  # deg
    division_probability: float
    roll_angle: float  # deg
    step_length: float  # m
    length_scale: float  # m per m of water coefficient
    max_branches: int
    max_tilt: float  # deg
    wind: tuple[float, float, float]  # a direction; 0 0 0: still air
    branch_spread: float  # m
    contact: str  # stop | slide


@dataclass(frozen=True)
class SurfaceParams:
    """Stage 4, the icicles' surface (paper 4.4)."""

    mode: str  # metaballs | tubes
    profile: str  # physical | paper
    tip_radius: float  # m
    growth_ratio: float  # m of radius per m of length
    impurity: float
    ripple_amplitude: float  # m
    ripple_frequency: float  # rad/m
    noise: float  # m
    base_extent: float  # m
    base_balls: int
    base_scale: float  # m per m of water coefficient
    voxel_size: float  # m
    face_budget: int  # faces
    error_px: float  # px
    curtain: float  # m


@dataclass(frozen=True)
class GlazeParams:
    """Glaze ice over the wet surface (paper 4.4.4)."""

    mode: str  # coat | metaballs | none
    min_radius: float  # m
    scale: float  # m per m of dUp/dDown
    lifetime: float
    edge: float  # m
    density: float  # balls per m^2
    voxel_size: float  # m
    runnels: float  # share of the coat's thickness
    smoothing: int  # Taubin steps


@dataclass(frozen=True)
class GroundIceParams:
    """Ice where the drops from the tips land."""

    mode: str  # none | mounds | stalagmites
    runoff: float  # share of the icicle's water coefficient
    merge: float  # m
    spread: float  # m per m of landed water
    height_scale: float  # m per m of landed water
    width: float  # m per m of length


@dataclass(frozen=True)
class GrowthParams:
    """Growth over time (`icefarm.job.frames`)."""

    frames: int


@dataclass(frozen=True)
class ProxyParams:
    """The approximate surface the water flows on for problem meshes (paper 5.1)."""

    mode: str  # auto | always | never
    face_budget: int  # faces
    alpha: float  # share of a part's bounding-box diagonal
    offset: float  # share of a part's bounding-box diagonal
    edge_length: float  # share of a part's bounding-box diagonal
