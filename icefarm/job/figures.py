"""What each step leaves in the job folder (its artifact) and the figures it reports
(``timings.json``), as functions of the results: declared with the step in `icefarm.job.graph`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .. import artifacts
from ..jobdir import DRIPS, ICE, ICE_BANDS, LANDING, PROXY, TRAJECTORIES, WATER
from ..params import StormParams
from ..stages import drip_rim_length, measure_trajectories
from .records import JobInputs, StageResults


def finite(value: float) -> float | None:
    """JSON has no NaN: an unmeasured value is null."""
    return float(value) if np.isfinite(value) else None


def finite_list(values: np.ndarray, digits: int = 3) -> list[float | None]:
    """Per-icicle figures for JSON, aligned with the trunks: an unmeasured one is null."""
    return [round(float(x), digits) if np.isfinite(x) else None for x in values]


def ice_mesh(r: StageResults) -> trimesh.Trimesh:
    """Stage 4's ice as a mesh, with the ripples' milky bands for the render's shimmer."""
    mesh = trimesh.Trimesh(r.ice.vertices, r.ice.faces, process=False)
    if r.ice.bands is not None:
        mesh.vertex_attributes[ICE_BANDS] = r.ice.bands
    return mesh


# ---------------------------------------------------------------------------- artifacts
def write_proxy(job_dir: Path, r: StageResults) -> None:
    artifacts.write_mesh(job_dir / PROXY, r.proxy.mesh)


def write_water(job_dir: Path, r: StageResults) -> None:
    assert r.water is not None
    artifacts.write_water_ply(job_dir / WATER, r.flow, r.water.supply, r.water.water)


def write_drips(job_dir: Path, r: StageResults) -> None:
    assert r.drips is not None
    artifacts.write_json(job_dir / DRIPS, artifacts.drips_to_json(r.drips))


def write_trajectories(job_dir: Path, r: StageResults) -> None:
    assert r.trajectories is not None
    artifacts.write_json(job_dir / TRAJECTORIES, artifacts.trajectories_to_json(r.trajectories))


def write_landing(job_dir: Path, r: StageResults) -> None:
    artifacts.write_json(job_dir / LANDING, artifacts.landing_to_json(r.landing, r.ground.heights, r.ground.columns))


def write_ice(job_dir: Path, r: StageResults) -> None:
    artifacts.write_mesh(job_dir / ICE, ice_mesh(r))


# ---------------------------------------------------------------------------- figures
def proxy_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    return {"proxy_reason": i.proxy_reason, "proxy_faces": r.proxy.faces, "proxy_components": r.proxy.components,
            "proxy_build_seconds": r.proxy.seconds}


def water_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    assert r.water is not None
    out: dict[str, Any] = {"flow_faces": len(r.flow.faces)}
    if r.water.storm is not None:
        out.update(storm_figures(r.water.storm, i.params.storm, i.params.water.pools))
    return out


def storm_figures(storm: Any, group: StormParams, pools: str) -> dict[str, Any]:
    """What a physical storm did: its kind, class and precipitation, the glaze's median
    thickness where the rain lands, where the water went, and whether full basins spilled
    (``water.pools``)."""
    from ..stages import precipitation_m

    ice = storm.ice[storm.catch > 0]  # where the rain lands (films thinned by running are not the storm's glaze)
    caught = storm.budget.caught or 1.0
    return {"storm_kind": group.kind, "storm_intensity": group.intensity,
            "precipitation_mm": round(1000 * precipitation_m(group.intensity, group.precipitation), 2),
            "storm_glaze_p50_mm": round(1000 * float(np.median(ice)), 2) if len(ice) else 0.0,
            "water_frozen": round(storm.budget.frozen / caught, 4), "water_shed": round(storm.budget.shed / caught, 4),
            "water_pooled": round(storm.budget.pooled / caught, 4), "water_pools": pools}


def drips_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    assert r.water is not None and r.drips is not None
    out: dict[str, Any] = {"icicles": len(r.drips.positions)}
    if r.water.storm is not None:
        rim = drip_rim_length(r.flow, r.drips.region_faces, i.gravity, i.params.drips.drip_limit)
        out.update(drip_rim_m=round(rim, 4), icicles_per_m=round(len(r.drips.positions) / rim, 2) if rim else 0.0)
    return out


def trajectories_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    traj = r.trajectories
    assert traj is not None
    t = measure_trajectories(traj, i.gravity)
    # a drop that falls straight onto the object grows no icicle (trajectories.contact)
    icicles = int(np.count_nonzero((np.asarray(traj.branch_parent) < 0) & (np.diff(traj.branch_offsets) > 1)))
    return {"icicles": icicles, "branches": traj.n_branches, "upward_share": finite(t.upward_share),
            "branch_spread_mm": finite(t.branch_spread_mm), "length_cv": finite(t.length_cv),
            "trunk_lengths_m": finite_list(t.trunk_lengths, 4)}


def ground_ice_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    grown = r.ground.heights[r.ground.heights > 0] * 1000
    return {"landing_points": len(r.landing), "stalagmites": len(grown), "columns": int(r.ground.columns.sum()),
            "stalagmite_median_mm": finite(np.median(grown)) if len(grown) else None,
            "stalagmite_max_mm": finite(grown.max()) if len(grown) else None}


def surface_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    ice = r.ice
    out: dict[str, Any] = {"ice_faces": len(ice.faces), "metaballs": ice.balls}
    if ice.coarse_voxel is not None:
        out["coarse_voxel_mm"] = round(1000 * ice.coarse_voxel, 3)
    if i.params.surface.curtain > 0:
        out["curtain_area_m2"] = round(ice.curtain_area, 6)
    return out


def measure_figures(i: JobInputs, r: StageResults) -> dict[str, Any]:
    m, fringe, glaze = r.measured.icicles, r.measured.fringe, r.measured.glaze
    return {
        "glaze_coverage": finite(glaze.coverage), "glaze_p10_mm": finite(glaze.p10_mm),
        "glaze_p50_mm": finite(glaze.p50_mm), "glaze_p90_mm": finite(glaze.p90_mm),
        "glaze_top_bottom": finite(glaze.top_bottom), "glaze_relief": finite(glaze.relief),
        "tip_radius_mm": finite(m.tip_radius_mm), "taper": finite_list(m.taper),
        "growth_ratio": finite_list(m.growth_ratio, 4), "profile_exponent": finite_list(m.profile_exponent),
        "ripple_amplitude_mm": finite(m.ripple_amplitude_mm), "ripple_wavelength_cm": finite(m.ripple_wavelength_cm),
        "ripple_depth_mm": finite(m.ripple_texture.depth_mm),
        "ripple_correlation_3cm": finite(m.ripple_texture.correlation_3cm),
        "ripple_crest_cv": finite(m.ripple_texture.crest_cv), "ripple_trunks": m.ripple_texture.trunks,
        "fringe_free_share": finite(fringe.free_share), "fringe_free_checked": fringe.checked,
        "fringe_length_contrast": finite(fringe.length_contrast),
    }
