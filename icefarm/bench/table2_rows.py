"""Table 2's rows: the paper's numbers, the objects that stand in for its Figure 16, and a measured row.

Data and records only, so that measuring (`icefarm.bench.table2`) and writing (`icefarm.bench.table2_write`)
both import them from here.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

from ..report import TABLE2_STAGES as STAGES

STAGE_TITLES = {"water": "Water coefficients", "drips": "Drip points", "trajectories": "Trajectories",
                "surface": "Surface modeling", "total": "Total time"}
# The bar Table 2 is held to: every row at least 50 times faster than the paper in all.
TARGET_SPEEDUP = 50.0
TARGET_ICE_FACTOR = 1.5


@dataclass(frozen=True)
class PaperRow:
    """One column of the paper's Table 2 (Figure 16 a-g); seconds per stage and in total."""

    key: str
    polygons: int
    icicles: int
    ice_polygons: int
    seconds: dict


PAPER_TABLE2: tuple[PaperRow, ...] = tuple(
    PaperRow(key, polys, icicles, ice, dict(zip((*STAGES, "total"), secs)))
    for key, polys, icicles, ice, secs in (
        ("a", 1617, 12, 10400, (0.1, 0.1, 0.1, 11, 11.3)),
        ("b", 2240, 300, 179428, (0.1, 0.5, 0.2, 55, 55.8)),
        ("c", 15536, 10, 749296, (0.5, 0.2, 0.1, 60, 60.8)),
        ("d", 3851, 20, 102594, (0.3, 0.1, 0.2, 20, 20.6)),
        ("e", 30780, 200, 390616, (5, 0.5, 0.5, 116, 122)),
        ("f", 11102, 200, 244188, (0.4, 0.5, 0.5, 19.5, 20.9)),
        ("g", 6660, 400, 131000, (0.3, 0.5, 1, 36, 37.8)),
    )
)


@dataclass(frozen=True)
class RowObject:
    """What stands in for one of the paper's objects.

    ``source`` is a file name in the meshes folder or ``generator:NAME``; ``size_m`` the
    object's height in meters; ``settings`` parameter values (``("group.name", value)``)
    that differ from the defaults besides ``drips.count`` and the calibrated voxel size.
    """

    source: str
    label: str
    size_m: float
    settings: tuple = ()

    def settings_text(self) -> str:
        return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in self.settings) or "defaults"

    @property
    def generated(self) -> bool:
        return self.source.startswith("generator:")


_NO_GLAZE = (("glaze.mode", "none"),)
# The paper's icicles, whose polygons Table 2 counts: Equation 1's cone at the slope and the
# bases of its era (icefarm's defaults grow carrot-shaped icicles about twice as wide at the
# base, with swollen bases: more ice, more polygons for the same voxel).
_PAPER_ICICLES = (("surface.profile", "paper"), ("surface.growth_ratio", 0.012),
                  ("surface.base_scale", 0.03), ("surface.base_extent", 0.01))

# Glaze ice covers whole wet surfaces, so it sets the polygon count: rows whose paper count
# is low for their icicles (a few hundred to a few thousand polygons per icicle) are
# modelled without glaze; c (10 icicles, 749,296 polygons) cannot be without it. Sizes
# keep the calibrated voxel at or below the tip radius with the default icicle lengths
# (small objects, shorter icicles: lengths follow the water, which climbs with the size).
ROW_OBJECTS: dict[str, RowObject] = {
    "a": RowObject("cow.obj", "cow", 0.15, _PAPER_ICICLES + _NO_GLAZE),
    "b": RowObject("generator:fountain", "fountain (generated)", 0.6, _PAPER_ICICLES + _NO_GLAZE),
    "c": RowObject("dragon.obj", "Stanford dragon", 0.3, _PAPER_ICICLES),
    "d": RowObject("stanford-bunny.obj", "Stanford bunny", 0.3, _PAPER_ICICLES + _NO_GLAZE),
    "e": RowObject("armadillo.obj", "Stanford armadillo", 0.3, _PAPER_ICICLES),
    "f": RowObject("stanford-bunny.obj", "Stanford bunny", 0.2, _PAPER_ICICLES + _NO_GLAZE),
    "g": RowObject("generator:roof", "house with eaves (generated)", 0.17, _PAPER_ICICLES + _NO_GLAZE),
}


@dataclass(frozen=True)
class Table2Row:
    """Our measurement of one row, beside the paper's.

    Attributes
    ----------
    paper : PaperRow
    object : RowObject
    input_faces, icicles, ice_faces : int
        Ours: faces of the prepared mesh, drip points found, faces of the ice mesh (median
        over the runs).
    target_ice_faces : int
        The paper's ice polygons times the run's ``scale``.
    voxel_size : float
        The calibrated ``surface.voxel_size``, in meters.
    seconds : dict
        Stage (and ``total``) to the list of measured seconds, one per repeat.
    """

    paper: PaperRow
    object: RowObject
    input_faces: int
    icicles: int
    ice_faces: int
    target_ice_faces: int
    voxel_size: float
    seconds: dict

    def median(self, stage: str) -> float:
        return statistics.median(self.seconds[stage])

    def speedup(self, stage: str) -> float:
        ours = self.median(stage)
        return self.paper.seconds[stage] / ours if ours > 0 else math.inf

    @property
    def ice_ratio(self) -> float:
        """Our ice faces over the target (1 = the paper's count)."""
        return self.ice_faces / self.target_ice_faces if self.target_ice_faces else math.nan

    @property
    def meets_target(self) -> bool:
        return (self.speedup("total") >= TARGET_SPEEDUP
                and 1 / TARGET_ICE_FACTOR <= self.ice_ratio <= TARGET_ICE_FACTOR)
