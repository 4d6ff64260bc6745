"""The registry of parameters: the paper's Table 1 and icefarm's own, each with a symbol,
a unit, a domain and a default (`PARAMS`), in stage order. Lengths are in meters, angles in
degrees. `icefarm.params` resolves and types them.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace
from typing import Any

from .errors import InputError


class Kind(enum.Enum):
    INT = "int"
    FLOAT = "float"
    CHOICE = "choice"
    VECTOR = "vector"
    TEXT = "text"


@dataclass(frozen=True)
class Param:
    group: str
    name: str
    symbol: str
    unit: str
    kind: Kind
    default: Any
    doc: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    zero_ok: bool = False  # a VECTOR that may be (0, 0, 0), meaning "none"
    mode: str = ""  # the only storm.mode that reads it ("": both)
    instead: str = ""  # what the other storm.mode uses in its place

    @property
    def key(self) -> str:
        return f"{self.group}.{self.name}"

    @property
    def domain(self) -> str:
        if self.kind is Kind.CHOICE:
            return " | ".join(self.choices)
        if self.kind is Kind.VECTOR:
            return "3 numbers (0 0 0: none)" if self.zero_ok else "3 numbers, not all zero"
        if self.kind is Kind.TEXT:
            return "text"
        low = "-inf" if self.low is None else _fmt(self.low)
        high = "inf" if self.high is None else _fmt(self.high)
        left = "]" if self.low_open or self.low is None else "["
        right = "[" if self.high_open or self.high is None else "]"
        return f"{left}{low}, {high}{right}"

    def validate(self, value: Any) -> Any:
        """Return ``value`` coerced to this parameter's type, or raise `InputError`."""
        if self.kind is Kind.CHOICE:
            if value not in self.choices:
                raise self._refuse(value)
            return value
        if self.kind is Kind.TEXT:
            if not isinstance(value, str) or not value:
                raise self._refuse(value)
            return value
        if self.kind is Kind.VECTOR:
            if isinstance(value, str):
                value = [v for v in value.replace("(", "").replace(")", "").replace(",", " ").split()]
            try:
                vec = [float(v) for v in value]
            except (TypeError, ValueError):
                raise self._refuse(value) from None
            if len(vec) != 3 or not all(map(math.isfinite, vec)) or not (any(vec) or self.zero_ok):
                raise self._refuse(value)
            return vec
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self._refuse(value)
        if self.kind is Kind.INT:
            if float(value) != int(value):
                raise self._refuse(value)
            value = int(value)
        else:
            value = float(value)
        if not math.isfinite(value) or not self._in_range(value):
            raise self._refuse(value)
        return value

    def _in_range(self, value: float) -> bool:
        if self.low is not None and (value < self.low or (self.low_open and value == self.low)):
            return False
        if self.high is not None and (value > self.high or (self.high_open and value == self.high)):
            return False
        return True

    def _refuse(self, value: Any) -> InputError:
        unit = f" ({self.unit})" if self.unit != "-" else ""
        return InputError(
            f"parameter {self.key} = {value!r} is out of its domain {self.domain}{unit}: {self.doc}"
        )


def _fmt(x: float) -> str:
    return f"{x:g}"


def _p(group, name, symbol, unit, kind, default, doc, **domain) -> Param:
    return Param(group, name, symbol, unit, kind, default, doc, **domain)


_F, _I = Kind.FLOAT, Kind.INT
# The default storm's breeze, m/s (storm.wind): from the asset's front, whichever axis is up
# (`icefarm.params.resolve` turns it with the gravity).
DEFAULT_WIND_MPS = 3.0

PARAMS: tuple[Param, ...] = (
    # The storm in physical units (beyond the paper; icefarm.stages.storm)
    _p("storm", "mode", "-", "-", Kind.CHOICE, "physical",
       "physical: the weather sets the ice in meters whatever the asset's size (glaze from the "
       "precipitation, icicles along every drip rim at drips.spacing, their length from the water "
       "their catchment drains); relative: the paper's knobs, relative to the object (water "
       "coefficients, drips.count, glaze.scale per meter of height; what Table 2 runs)",
       choices=("physical", "relative")),
    _p("storm", "kind", "-", "-", Kind.CHOICE, "freezing_rain",
       "freezing_rain (glaze on all the rain reaches, icicles at the drip rims) or meltwater (snow "
       "melting on the upper surfaces: little glaze away from the rims, long icicles at the eaves)",
       choices=("freezing_rain", "meltwater")),
    _p("storm", "intensity", "-", "-", Kind.CHOICE, "moderate",
       "the utilities' freezing-rain classes by radial ice on a wire: light 6 mm (18 mm of "
       "precipitation), moderate 13 mm (37 mm), severe 25 mm (73 mm); Jones 1998: P = pi R rho_i/rho_w",
       choices=("light", "moderate", "severe")),
    _p("storm", "precipitation", "P", "mm", _F, 0.0,
       "precipitation depth in mm of water (rain, or melted snow for meltwater); 0: the "
       "intensity's", low=0.0),
    _p("storm", "freeze", "-", "-", _F, 0.5,
       "share of the rain on a level face that freezes where it lands (a heat budget per area); "
       "the rest runs off towards the rims", low=0.0, high=1.0),
    _p("storm", "wall_freeze", "-", "-", _F, 0.5,
       "freezing budget of a vertical or downward face over a level one's (they lose less heat "
       "and shed their film faster)", low=0.0, high=1.0),
    _p("storm", "wind", "-", "m/s", Kind.VECTOR, [0.0, 0.0, -DEFAULT_WIND_MPS],
       "the wind during freezing rain, a velocity (its part across gravity counts): the rain "
       "slants (drops fall at about 5 m/s), walls and signs facing the wind glaze and drip, the "
       "lee stays dry. Default: a light 3 m/s breeze from the asset's front (+Z for Y-up, -Y for "
       "Z-up: the side cameras see at azimuth 0), as freezing rain nearly always comes with some "
       "wind; 0,0,0: still air, rain along gravity. "
       "trajectories.wind bends the icicles",
       zero_ok=True),
    _p("storm", "max_icicles", "-", "-", _I, 2000,
       "budget of icicles for huge assets: drip points run along every wet drip rim at "
       "drips.spacing up to this many (drips.count is the relative mode's)", low=0),
    _p("storm", "flow_edge", "-", "m", _F, 0.025,
       "box-modelled assets: the surface the water flows on is refined to edges at most this "
       "long, so large faces carry their water to the rims (0: never)", low=0.0),
    # Stage 1: water coefficients (paper 4.1)
    _p("water", "source", "ss", "-", Kind.TEXT, "auto",
       "rain source surface: 'auto' (a rectangle above the object, facing along gravity) or a mesh file"),
    _p("water", "gravity", "g", "-", Kind.VECTOR, [0.0, -1.0, 0.0],
       "direction of gravity (normalised); nothing else assumes Y-up"),
    _p("water", "rays", "nr", "-", _I, 4000, "number of rain rays cast from the source surface", low=1),
    _p("water", "influence_radius", "rii", "m", _F, 0.01,
       "vertices this close to a rain hit join the water supply", low=0.0, low_open=True),
    _p("water", "pools", "-", "-", Kind.CHOICE, "ignore",
       "water caught in basins: ignore (the paper: it stays there) or overflow (a full basin spills "
       "over its rim: fountains, gutters; a physical storm's pooled water runs on over the lip "
       "to the next basin or a drip rim, the relative mode adds the basin's depth to the water "
       "of walks that end there)",
       choices=("ignore", "overflow")),
    # Stage 2: drip points (paper 4.2)
    _p("drips", "count", "ns", "-", _I, 24, "number of drip points, one icicle each (storm.mode relative; "
       "physical runs them along the rims at drips.spacing, up to storm.max_icicles)", low=0),
    _p("drips", "drip_limit", "dl", "deg", _F, 75.0,
       "water drips where every vertex normal of a face lies within this angle of gravity",
       low=1.0, high=90.0, low_open=True, high_open=True),
    _p("drips", "spacing", "-", "m", _F, 0.025,
       "drip points never lie closer than this (icicles on eaves and wires settle 2.3-2.5 cm apart)",
       low=0.0),
    _p("drips", "min_fall", "-", "m", _F, 0.05,
       "no icicle where a drop lands this soon below its drip point (on the object or the ground "
       "of a grounded object): there is no room to hang, the water lands there; 0 keeps all",
       low=0.0),
    _p("drips", "min_length", "-", "m", _F, 0.02,
       "no icicle where the water would grow one shorter than this (kL x water): the drop "
       "freezes in place as glaze; 0 keeps all", low=0.0),
    _p("drips", "distribution", "-", "-", Kind.CHOICE, "water",
       "where drip points go: water (weighted by water, towards the lowest rim of each drip region: "
       "lips, eaves, spouts) or area (the paper: uniform over the drip region)",
       choices=("water", "area")),
    _p("drips", "ground_clearance", "-", "height", _F, 0.02,
       "no icicles this close to the object's lowest point (a fraction of its height): it rests "
       "on the ground there; 0 for hanging objects", low=0.0, high=1.0, high_open=True),
    # Stage 3: trajectories (paper 4.3)
    _p("trajectories", "curve_angle", "c", "deg", _F, 2.0,
       "turn applied at each L-system generation; 0 gives straight icicles",
       low=0.0, high=360.0, high_open=True),
    _p("trajectories", "division_probability", "d", "-", _F, 0.1,
       "probability that a generation splits off a branch", low=0.0, high=1.0),
    _p("trajectories", "roll_angle", "au", "deg", _F, 360.0,
       "roll of growth and dispersal; each generation rolls by au*137.5/360 deg", low=0.0, high=360.0),
    _p("trajectories", "step_length", "F", "m", _F, 0.004,
       "length of one L-system F segment", low=0.0, low_open=True),
    _p("trajectories", "length_scale", "kL", "m/m", _F, 2.0,
       "icicle length per meter of water coefficient: sets the number of generations",
       low=0.0, low_open=True),
    _p("trajectories", "max_branches", "-", "-", _I, 4,
       "branches per icicle at most; further divisions grow the trunk instead (real icicles carry "
       "a few side tips; 32 made a storm's metre-long icicles into tinsel; Table 2 keeps 32)", low=1),
    _p("trajectories", "max_tilt", "-", "deg", _F, 60.0,
       "bends saturate: no segment leans further than this from gravity, so no icicle curls up",
       low=0.0, high=90.0),
    _p("trajectories", "wind", "-", "-", Kind.VECTOR, [0.0, 0.0, 0.0],
       "direction the wind blows (its horizontal part is used): every icicle bends that way; "
       "0 0 0 for still air (bends spread at random)", zero_ok=True),
    _p("trajectories", "branch_spread", "-", "m", _F, 0.02,
       "a branch leaves its parent at 30 deg and holds that angle until it is this far aside, "
       "then grows on parallel (the paper's p1'' with one F: 2 mm); a late branch holds it for a "
       "third of what it grows at most, a side tip beside its parent's", low=0.0),
    _p("trajectories", "contact", "-", "-", Kind.CHOICE, "stop",
       "what an icicle does where it meets the object below it: stop (it ends touching the surface, "
       "a column, as real icicles do) or slide (the paper 4.3.1: it runs down the surface and drips "
       "again where the surface falls away; a fat ridge of icicle along the surface)",
       choices=("stop", "slide")),
    # Stage 4: surface (paper 4.4)
    _p("surface", "mode", "-", "-", Kind.CHOICE, "metaballs",
       "metaballs (fused, the paper's surface) or tubes (swept tubes, instant preview)",
       choices=("metaballs", "tubes")),
    _p("surface", "profile", "-", "-", Kind.CHOICE, "physical",
       "radius along an icicle: physical (tip + k d^3/4 from the tip, as measured on real icicles) "
       "or paper (Equation 1: a straight cone, tip + t (L - x))", choices=("physical", "paper")),
    _p("surface", "tip_radius", "tip", "m", _F, 0.00244,
       "radius of the hemispherical drop at the tip (Maeno: 2.44 mm)", low=0.0, low_open=True),
    _p("surface", "growth_ratio", "t", "m/m", _F, 0.0625,
       "base radius added per meter of icicle length (base = tip + t L); real icicles widen their "
       "diameter by 1/32 to 1/8 of their length, t = 0.016 to 0.0625", low=0.0),
    _p("surface", "impurity", "-", "-", _F, 0.7,
       "dissolved salts in the water: 0 pure (smooth, clear icicles), about 0.7 tap water (rippled, "
       "cloudy core), 1 the full ripple amplitude; scales the ripples and the render's cloudiness",
       low=0.0, high=1.0),
    _p("surface", "ripple_amplitude", "as", "m", _F, 0.00105,
       "depth of the ripples' crests at impurity 1, where a crest is whole; the icicle gets as * impurity, "
       "each icicle from 0.6 to 1.15 times that. Crests fade and tilt a little around the trunk, so "
       "about 3/4 of it shows in the radius measured around the trunk (real: 0.5-1 mm)", low=0.0),
    _p("surface", "ripple_frequency", "fs", "rad/m", _F, 628.3,
       "angular frequency of the ripples (628 rad/m: 1 cm apart, as on real icicles)", low=0.0),
    _p("surface", "noise", "nc", "m", _F, 0.0004,
       "metaballs move at random up to this far off the trajectory", low=0.0),
    _p("surface", "base_extent", "eb", "m", _F, 0.02,
       "ice at the base of an icicle spreads this far over the object", low=0.0),
    _p("surface", "base_balls", "nmb", "-", _I, 30,
       "metaballs in the base of each icicle; they add up, so more balls swell the base", low=0),
    _p("surface", "base_scale", "kb", "m/m", _F, 0.2,
       "radius of a base ball at the drip point per meter of water coefficient (Equation 2); "
       "the icicle's own base is t kL wc wide, so kb above t kL makes a swelling", low=0.0),
    _p("surface", "voxel_size", "-", "m", _F, 0.001,
       "edge of a marching-cubes voxel; must resolve the tip radius", low=0.0, low_open=True),
    _p("surface", "face_budget", "-", "faces", _I, 3_000_000,
       "storm.mode physical: the ice mesh holds about this many faces at most (for lookdev's 480x360 "
       "view and its ice view; a render config that shows less scales it down: preview, 320x240 of "
       "the whole object, to 7 %); past it the "
       "marching-cubes voxels of the icicles (never past the tip radius) and of the glaze coat "
       "grow (a 3 m house's icicles at 1 mm were 27 M faces); 0: off. The relative mode keeps "
       "the voxel sizes (Table 2's polygon counts)", low=0),
    _p("surface", "error_px", "-", "px", _F, 0.15,
       "storm.mode physical: how far the icicles' mesh may lie off their exact surface, in pixels of "
       "a 480-pixel view framing the object (preview: 2.5 times more, as large as lookdev's ice view "
       "shows it); "
       "where that allows and one lattice would not hold "
       "surface.face_budget, their thick parts are meshed on a lattice 3 times coarser than their "
       "tips, without ripples (a 3 m house: 7.8 M faces to under 3 M); 0: one lattice", low=0.0),
    _p("surface", "curtain", "-", "m", _F, 0.0,
       "icicles whose trunks hang closer than this are joined by a sheet of ice, thick near their "
       "bases, draped between them, down to the shorter one's tip (as along eaves); 0: none; "
       "metaballs surface only",
       low=0.0),
    # Glaze ice (paper 4.4.4)
    _p("glaze", "mode", "-", "-", Kind.CHOICE, "coat",
       "glaze ice over the wet surface: coat (one continuous clear coat, Equation 3 thick), "
       "metaballs (the paper's balls, glaze.density per square meter: lumpy) or none",
       choices=("coat", "metaballs", "none")),
    _p("glaze", "min_radius", "minGI", "m", _F, 0.0,
       "minimum thickness of the glaze ice (Equation 3; the paper's default 0 keeps lt's "
       "top/bottom contrast)", low=0.0),
    _p("glaze", "scale", "s", "m/m", _F, 0.01,
       "glaze thickness per meter of dUp/dDown (Equation 3): about 1.6 mm on a 0.3 m object, "
       "5 mm on a 1 m roof at lt 0.5", low=0.0),
    _p("glaze", "lifetime", "lt", "-", _F, 0.5,
       "water drop lifetime: 0 thick high up (freezes where it lands), 1 thick low down (runs first)",
       low=0.0, high=1.0),
    _p("glaze", "edge", "-", "m", _F, 0.01,
       "coat mode: past the edge of the wet surface the coat thins to nothing over this distance "
       "(0: it ends in a step)", low=0.0),
    _p("glaze", "density", "-", "1/m^2", _F, 50000.0,
       "metaballs mode: balls per square meter of wet surface (the paper's ngi over the wet area)",
       low=0.0),
    _p("glaze", "balls", "ngi", "-", _I, 20000,
       "legacy (before glaze.mode): 0 means glaze.mode none; a positive count turns the glaze on "
       "(glaze.mode none becomes coat) and is otherwise ignored: use glaze.density", low=0),
    _p("glaze", "voxel_size", "-", "m", _F, 0.004,
       "edge of a marching-cubes voxel for the glaze (the coat's thickness does not depend on it; "
       "parts thinner than two voxels, wet on one side only, need a finer one); coarser than "
       "surface.voxel_size keeps the mesh light", low=0.0, low_open=True),
    _p("glaze", "runnels", "-", "-", _F, 0.35,
       "coat mode: relief of the runnels and frozen drops the film leaves as it freezes running down "
       "sloped and vertical faces, a share of the coat's thickness on a vertical face (ridges 1-4 cm "
       "apart, beads along them; level tops stay smooth, the ice's volume stays); 0: an even coat",
       low=0.0, high=1.0),
    _p("glaze", "smoothing", "-", "-", _I, 10,
       "coat mode: Taubin steps that smooth the coat's face (its field is a patchwork of the surface "
       "samples' planes, whose kinks reflect the sky as ragged flecks up close); vertices move at "
       "most a tenth of glaze.voxel_size and the icicles keep their shape; 0: off", low=0),
    # Ice where the water dripping off the tips lands (beyond the paper)
    _p("ground_ice", "mode", "-", "-", Kind.CHOICE, "none",
       "ice where the drops from the tips land (on the ground or a lower part of the object): "
       "none, mounds (a low cap around each landing point) or stalagmites (a mound and a blunt "
       "stalagmite rising towards the tip; one that reaches it fuses into a column); metaballs surface only",
       choices=("none", "mounds", "stalagmites")),
    _p("ground_ice", "runoff", "-", "-", _F, 0.5,
       "share of an icicle's water coefficient that drips off its tips instead of freezing on it",
       low=0.0, high=1.0),
    _p("ground_ice", "merge", "-", "m", _F, 0.02,
       "landing points closer than this merge into one (their water adds up); below the 2.5 cm "
       "between icicles, so a branch's drops join its trunk's, a neighbour's stay apart", low=0.0),
    _p("ground_ice", "spread", "-", "m/m", _F, 0.6,
       "mound radius per meter of landed water; the mound is a quarter as high", low=0.0),
    _p("ground_ice", "height_scale", "-", "m/m", _F, 1.0,
       "stalagmite height per meter of landed water, never past the tip above it", low=0.0),
    _p("ground_ice", "width", "-", "m/m", _F, 0.35,
       "base radius a stalagmite adds per meter of its length (icicles: surface.growth_ratio); "
       "its top is twice the icicle's tip radius", low=0.0),
    # Growth over time (beyond the paper; icefarm.job.frames)
    _p("growth", "frames", "-", "-", _I, 0,
       "also render the ice at this many moments from the first drip to full growth, into "
       "growth/ (meshes, frames, an MP4, a time-sampled USD); 0: only the full growth",
       low=0, high=240),
    # Approximate surface for problem meshes (paper 5.1)
    _p("proxy", "mode", "-", "-", Kind.CHOICE, "auto",
       "build an approximate surface for the water: auto (for problem meshes), always or never",
       choices=("auto", "always", "never")),
    _p("proxy", "face_budget", "-", "-", _I, 60000,
       "meshes with more faces are decimated to this many for the water flow (parts far apart "
       "share it by area)", low=100),
    _p("proxy", "alpha", "-", "bbox", _F, 0.01,
       "alpha-wrap ball size as a fraction of each part's bounding-box diagonal (parts farther "
       "apart than this are built one by one, each at its own scale)", low=0.0, low_open=True),
    _p("proxy", "offset", "-", "bbox", _F, 0.002,
       "alpha-wrap offset as a fraction of each part's bounding-box diagonal", low=0.0, low_open=True),
    _p("proxy", "edge_length", "-", "bbox", _F, 0.01,
       "target edge of the remeshed proxy as a fraction of each part's bounding-box diagonal",
       low=0.0, low_open=True),
)


# What only one storm.mode reads, and what the other one uses in its place: a knob the job's
# mode ignores is warned about (`icefarm.params.idle_keys`) and marked in `icefarm params`.
_RELATIVE_USES = "the paper's water coefficients (water.rays), drips.count and glaze.scale"
_MODE_ONLY: dict[str, tuple[str, str]] = {
    "water.rays": ("relative", "storm.precipitation or storm.intensity (every face gets its share of the rain)"),
    "water.influence_radius": ("relative", "storm.precipitation or storm.intensity"),
    "drips.count": ("relative", "drips.spacing (icicles along every drip rim) and storm.max_icicles"),
    "glaze.scale": ("relative", "storm.intensity or storm.precipitation (glaze in mm of ice) and storm.freeze"),
    "surface.face_budget": ("physical", "surface.voxel_size and glaze.voxel_size"),
    "surface.error_px": ("physical", "surface.voxel_size"),
    **{p.key: ("physical", _RELATIVE_USES) for p in PARAMS if p.group == "storm" and p.name != "mode"},
}
PARAMS = tuple(replace(p, mode=_MODE_ONLY[p.key][0], instead=_MODE_ONLY[p.key][1]) if p.key in _MODE_ONLY else p
               for p in PARAMS)
