"""What ``icefarm run`` prints after a job: the storm, and the measures to judge its ice by."""

from __future__ import annotations

import statistics

import click

# A job whose icicles are fewer than this, or whose trunks are shorter than this (m), or whose
# glaze is thinner than this (mm) reads as bare at lookdev: the run summary says so.
FEW_ICICLES = 5
SHORT_TRUNK_M = 0.01
THIN_GLAZE_MM = 0.5
# A storm that leaves this share of its water standing in basins (water.pools: ignore) gets a
# hint: a fountain's or a gutter's basins are full, and spill (the fountain: 27 %).
POOLED_HINT = 0.1


# Where a figure's real range lies, and the knob that moves it back: (low, high, below, above).
VERDICTS = {
    "taper": (3.0, None, "surface.growth_ratio up, or surface.profile=physical", ""),
    "growth_ratio": (0.03, 0.13, "surface.growth_ratio up",
                     "a lighter storm.intensity (short icicles thicken with the glaze)"
                     " or a lower surface.growth_ratio"),
    "profile_exponent": (0.6, 0.9, "surface.profile=physical", "surface.profile=physical"),
    "tip_radius_mm": (2.0, 3.0, "surface.tip_radius up (2.44 mm)", "surface.tip_radius down (2.44 mm)"),
    "fringe_free_share": (0.85, None, "drips.spacing up (icicles crowd each other)", ""),
    "fringe_length_contrast": (2.5, None, "an even fringe: storm.kind=meltwater or a severer storm lets a few "
                               "icicles outgrow the others", ""),
}


# The icicles' shapes are measured on the mesh (its voxels, ripples, glaze at the base): a
# median within this share of its real range's ends is not called out of it.
SHAPE_SLACK = 0.1
SHAPE_FIGURES = ("taper", "growth_ratio", "profile_exponent", "tip_radius_mm")


def verdict(key: str, value: float | None) -> str:
    """``""`` when ``value`` lies in the real range of figure ``key`` (`VERDICTS`; shapes
    within `SHAPE_SLACK`), else the words that say it does not and which knob moves it."""
    if value is None or key not in VERDICTS:
        return ""
    low, high, below, above = VERDICTS[key]
    slack = SHAPE_SLACK if key in SHAPE_FIGURES else 0.0
    if low is not None and value < low * (1 - slack):
        return f" -- below the real range: {below}"
    if high is not None and value > high * (1 + slack):
        return f" -- above the real range: {above}"
    return ""


def print_storm(timings: dict) -> None:
    """What a physical storm did, and one warning line when it left almost nothing visible."""
    kind = timings["storm_kind"].replace("_", " ")
    icicles, per_m = timings.get("icicles", 0), timings.get("icicles_per_m", 0.0)
    dripped = "icicles" in timings  # --until water: no drip points yet, nothing to say of icicles
    click.echo(f"  storm: {timings['storm_intensity']} {kind}, {timings['precipitation_mm']:.0f} mm of water: "
               f"glaze {timings['storm_glaze_p50_mm']:.1f} mm (p50 where the rain lands); "
               + (f"{icicles} icicles, {per_m:.0f} per m of drip rim ({timings.get('drip_rim_m', 0.0):.2f} m); "
                  if dripped else "")
               + f"the water: {100 * timings['water_frozen']:.0f} % glaze, {100 * timings['water_shed']:.0f} % "
               f"dripped, {100 * timings['water_pooled']:.0f} % pooled")
    lengths = timings.get("trunk_lengths_m") or []
    longest = max([v for v in lengths if v is not None], default=0.0)
    if not dripped:
        pass
    elif icicles < FEW_ICICLES or (lengths and longest < SHORT_TRUNK_M):
        size = "under 1 cm" if lengths and longest < SHORT_TRUNK_M else f"up to {100 * longest:.0f} cm"
        what = "no icicles" if icicles == 0 else f"{icicles} icicles {size}"
        click.echo(f"  warning: {what}: a {timings['storm_intensity']} storm on a small object or one with "
                   "little rim; try storm.intensity=severe, or storm.wind=0,0,5 (m/s) to drive the rain onto "
                   "upright faces (a sign, a wall) that face it")
    elif timings["storm_glaze_p50_mm"] < THIN_GLAZE_MM:
        click.echo(f"  warning: glaze {timings['storm_glaze_p50_mm']:.1f} mm: too thin to read; raise "
                   "storm.precipitation or storm.freeze")
    if timings["water_pooled"] >= POOLED_HINT and timings.get("water_pools") == "ignore":
        click.echo(f"  note: {100 * timings['water_pooled']:.0f} % of the water stays in basins; if they are full "
                   "(a fountain, a gutter), --set water.pools=overflow spills it over their rims to grow icicles "
                   "below")


def print_job_summary(timings: dict) -> None:
    """The run's closing lines: trajectories, storm, ice, ground ice, curtains, tips and ripples, glaze,
    the ground, and the icicles' shapes, each beside what real ones measure."""
    if timings.get("ice_layer_skipped"):
        click.echo(f"  warning: no ice_layer.usda: {timings['ice_layer_skipped']}")
    inside_out = (timings.get("problems") or {}).get("inside_out_faces", 0)
    if inside_out:
        click.echo(f"  mesh: {inside_out} faces came wound inside out (normals pointing in); turned outward")
    if "upward_share" in timings:
        share, spread, cv = (timings.get(k) for k in ("upward_share", "branch_spread_mm", "length_cv"))
        click.echo(f"  trajectories: {'-' if share is None else f'{100 * share:.0f}'} % of segments upward "
                   f"(real: 0); branches of 3 cm and more spread {'-' if spread is None else f'{spread:.0f}'} "
                   f"mm from their parent; trunk lengths vary {'-' if cv is None else f'{100 * cv:.0f}'} % "
                   "(std / mean)")
    if "storm_kind" in timings:
        print_storm(timings)
    if "ice_faces" not in timings:
        return
    click.echo(f"  ice: {timings['ice_faces']} faces, {timings.get('icicles', 0)} icicles")
    if "landing_points" in timings:
        median, top = timings.get("stalagmite_median_mm"), timings.get("stalagmite_max_mm")
        click.echo(f"  ground ice: {timings['landing_points']} landing points, {timings.get('stalagmites', 0)} "
                   f"stalagmites ({timings.get('columns', 0)} columns)"
                   + ("" if median is None else f", {median:.0f} mm high (median), {top:.0f} mm at most"))
    if "curtain_area_m2" in timings:
        click.echo(f"  curtains: {1e4 * timings['curtain_area_m2']:.0f} cm^2 of sheet between close icicles")
    tip, amplitude, ripple = (timings.get(k) for k in ("tip_radius_mm", "ripple_amplitude_mm", "ripple_wavelength_cm"))
    click.echo(f"  tip radius {'-' if tip is None else f'{tip:.2f}'} mm (real: 2.44 mm); ripples "
               + ("none above the mesh's noise in the radius spectrum" if amplitude is None
                  else f"{amplitude:.2f} mm deep, {ripple:.2f} cm apart")
               + " (real: 0.5-1 mm, about 1 cm apart, where the water is impure)" + verdict("tip_radius_mm", tip))
    coarse = timings.get("coarse_voxel_mm")
    if coarse is not None:
        click.echo(f"  face budget: the icicles' thick parts meshed at {coarse:.1f} mm, too coarse to carry ripples; "
                   "surface.error_px=0 meshes them on one lattice, rippled, with more faces")
    depth, corr, cv = (timings.get(k) for k in ("ripple_depth_mm", "ripple_correlation_3cm", "ripple_crest_cv"))
    if depth is not None and corr is not None and cv is not None:
        click.echo(f"  ripple texture on {timings.get('ripple_trunks', 0)} trunks of 10 cm and more: {depth:.2f} mm "
                   f"deep, radius 3 cm apart correlates {corr:.2f}, crest spacing varies {cv:.2f} (CV) "
                   "(natural: at most 0.6, and 0.1-0.35)")
    free, contrast = timings.get("fringe_free_share"), timings.get("fringe_length_contrast")
    if free is not None or contrast is not None:
        click.echo("  fringe: " + ("-" if free is None else f"{100 * free:.0f} %")
                   + f" of {timings.get('fringe_free_checked', 0)} icicles of 3 cm and more hang free at half "
                   "their length; the longest of each and its 4 nearest (10 cm) "
                   + ("-" if contrast is None else f"{contrast:.1f}") + " times the shortest "
                   "(real fringes: 85 % and more free, 2.5 times and more)"
                   + (verdict("fringe_free_share", free) or verdict("fringe_length_contrast", contrast)))
    coverage = timings.get("glaze_coverage")
    if coverage is not None:
        p10, p50, p90, ratio = (timings.get(k) for k in ("glaze_p10_mm", "glaze_p50_mm", "glaze_p90_mm",
                                                        "glaze_top_bottom"))
        relief = timings.get("glaze_relief")
        click.echo(f"  glaze: covers {100 * coverage:.1f} % of the wet surface, "
                   + ("-" if p50 is None else f"{p10:.1f} / {p50:.1f} / {p90:.1f} mm thick (p10/p50/p90)")
                   + ("" if ratio is None else f", top/bottom {ratio:.2f}")
                   + ("" if relief is None else f"; runnels on steep faces: the thickness strays {100 * relief:.0f} % "
                      "from the storm's even coat (an even varnish: a few %)"))
    gap = timings.get("ground_gap_mm")
    if gap is not None:
        click.echo(f"  ground: the object's lowest point {gap:.1f} mm above the ground plane"
                   + (" (stands on it)" if timings.get("placement") == "ground" else " (hanging)"))
    for key, what, real, fmt in (("taper", "taper (radius near the base / tip, icicles of 3 cm and more)",
                                  "a carrot: 3 and more", ".1f"),
                                 ("growth_ratio", "growth ratio (base - tip diameter) / length",
                                  "1/32-1/8, 0.03-0.13", ".3f"),
                                 ("profile_exponent", "profile exponent n of r - tip ~ d^n", "3/4", ".2f")):
        values = [v for v in timings.get(key) or [] if v is not None]  # None: too short to measure
        if values:
            median = statistics.median(values)
            click.echo(f"  {what}: median {median:{fmt}}, "
                       f"range {min(values):{fmt}}-{max(values):{fmt}} (real: {real}){verdict(key, median)}")
