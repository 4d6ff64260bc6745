"""Stage 4: icicles, bases and glaze fused into one mesh."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ...metaballs import Balls, concat_balls, fuse_fields, polygonize, sample_field
from ..drips import DripResult
from ..trajectories import TrajectoryResult
from ..water import WaterResult
from .bases import base_balls
from .glaze import COAT_SHEET, glaze_balls
from .icicles import icicle_balls
from .measure import measure_icicles
from .tubes import tube_mesh


@dataclass(frozen=True)
class IceResult:
    """The ice: icicles, bases and glaze fused into one mesh, with measured plausibility.

    Attributes
    ----------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound triangles; watertight in metaball mode, one closed tube per
        branch in tubes mode.
    tip_radius_mm : float
        Distance from each trunk's tip point to the ice surface ahead of it (median over
        the drop's mesh vertices), median over icicles, in millimeters; nan without icicles.
    length_to_diameter : (i,) float64
        Per icicle trunk (in branch order): trunk length over the base diameter measured on
        the mesh (a line fitted to the trunk's radius along its length, taken at x = 0).
        Real icicles: 8 to 32. NaN where a trunk cannot be measured: too short for four
        radius samples between 30 % and 90 % of its length (under 5 mm), or a fitted base
        radius that is not positive. Entries stay aligned with the trunks, so consumers
        drop the NaN themselves (the CLI's summary does).
    ripple_wavelength_cm : float
        Dominant period of the trunks' radius along their length, measured on the mesh,
        in centimeters (real icicles: about 1 cm); nan when ``ripple_amplitude`` is 0 or
        no trunk is long enough to show two ripples.
    balls : int
        Metaballs in the fields: icicles, bases and glaze (0 in tubes mode).
    """

    vertices: np.ndarray
    faces: np.ndarray
    tip_radius_mm: float
    length_to_diameter: np.ndarray
    ripple_wavelength_cm: float
    balls: int


def ice_mesh(ice: Balls, coat: Balls, voxel: float, coat_voxel: float):
    """The icicles with their bases, and the glaze, as one watertight mesh.

    With ``coat_voxel <= voxel`` (or no glaze) all balls add into one field polygonised at
    ``voxel``: the glaze fuses smoothly with the bases. Otherwise the icicles and bases
    are polygonised at ``voxel`` (which the tip radius needs), the glaze alone at the
    coarser ``coat_voxel`` (it covers the whole wet surface, so its face count rules the
    mesh: about ``(coat_voxel / voxel)^2`` times fewer faces), and the two closed surfaces
    are joined by a boolean union (`fuse_fields`).

    Parameters
    ----------
    ice, coat : Balls
        Icicle chains and bases; glaze.
    voxel, coat_voxel : float
        ``surface.voxel_size`` and ``glaze.voxel_size``, in meters.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound, watertight.
    """
    if len(coat) == 0 or coat_voxel <= voxel:
        return polygonize(concat_balls(ice, coat), voxel)
    coat_field = sample_field(coat, coat_voxel, name="glaze.voxel_size")
    return fuse_fields(sample_field(ice, voxel), coat_field)


def build_ice(object_mesh: trimesh.Trimesh, flow_mesh: trimesh.Trimesh, water: WaterResult,
              drips: DripResult, trajectories: TrajectoryResult, surface: dict, glaze: dict,
              gravity: np.ndarray, rng: np.random.Generator) -> IceResult:
    """Stage 4: icicles, their bases and glaze ice as one mesh (paper 4.4).

    ``surface["mode"] == "metaballs"``: one watertight mesh of the icicle chains, the
    bases and the glaze (`ice_mesh`: the glaze on its own coarser lattice, joined by a
    boolean union, or all in one field). ``"tubes"``: each branch as its own closed tube
    (`tube_mesh`), without bases or glaze: an instant preview.

    Parameters
    ----------
    object_mesh : trimesh.Trimesh
        The object, in meters; the drip points lie on it and the bases grow on it.
    flow_mesh : trimesh.Trimesh
        The surface stages 1-2 ran on (the object or its proxy); the glaze grows on it.
    water : WaterResult
        Per vertex of ``flow_mesh``.
    drips : DripResult
        Drip points on ``object_mesh``.
    trajectories : TrajectoryResult
        Branch polylines, base to tip, in meters.
    surface, glaze : dict
        ``params.resolve()["surface"]`` and ``["glaze"]``.
    gravity : (3,) float
        Direction of gravity (orients the first frame of each tube).
    rng : numpy.random.Generator
        Noise, base and glaze ball positions.

    Returns
    -------
    IceResult

    Raises
    ------
    ValueError
        Inputs of inconsistent shapes.
    InputError
        A voxel size (``surface.voxel_size`` or ``glaze.voxel_size``) too fine for the
        extent of the ice.
    """
    g = np.asarray(gravity, dtype=np.float64).reshape(-1)
    if g.shape != (3,) or not np.isfinite(g).all() or not g.any():
        raise ValueError(f"gravity must be 3 finite numbers, not all zero; got {gravity!r}")
    nv = len(flow_mesh.vertices)
    for name in ("supply", "water", "d_up", "d_down"):
        if len(getattr(water, name)) != nv:
            raise ValueError(f"water.{name} has {len(getattr(water, name))} values for {nv} flow-mesh vertices")
    k = len(drips.positions)
    if not (len(drips.normals) == len(drips.water) == len(drips.faces) == k):
        raise ValueError("drips.positions, normals, water and faces differ in length")
    if len(drips.faces) and (np.min(drips.faces) < 0 or np.max(drips.faces) >= len(object_mesh.faces)):
        raise ValueError("drips.faces index faces outside object_mesh")
    off = np.asarray(trajectories.branch_offsets)
    if off.ndim != 1 or len(off) != trajectories.n_branches + 1 or (len(off) and off[-1] != len(trajectories.points)):
        raise ValueError("trajectories.branch_offsets must have n_branches + 1 entries ending at len(points)")
    if surface["mode"] == "tubes":
        verts, faces = tube_mesh(trajectories, surface, g)
        n_balls = 0
    else:
        voxel, coat_voxel = surface["voxel_size"], glaze["voxel_size"]
        ice = concat_balls(icicle_balls(trajectories, surface, rng), base_balls(object_mesh, drips, surface, rng))
        coarse = coat_voxel > voxel
        coat = glaze_balls(flow_mesh, water, glaze, rng, min_sheet=COAT_SHEET * coat_voxel if coarse else 0.0)
        verts, faces = ice_mesh(ice, coat, voxel, coat_voxel)
        n_balls = len(ice) + len(coat)
    tip_mm, ratios, wavelength = measure_icicles(verts, faces, trajectories, surface)
    return IceResult(verts, faces, tip_mm, ratios, wavelength, n_balls)
