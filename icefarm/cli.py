"""The ``icefarm`` command line."""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

import click

from . import __version__, params
from .errors import InputError, Interrupted, one_line_each
from .jobdir import JobState, read_job, stage_phrase
from .placement import PLACEMENTS


class _Group(click.Group):
    """Turns `InputError` into one clean line and exit status 2 instead of a traceback;
    Ctrl-C exits 130 (128 + the signal), not 1 like a failed job."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as exc:
            click.echo(one_line_each(f"error: {exc}"), err=True)
            sys.exit(2)
        except KeyboardInterrupt as exc:
            stop = exc if isinstance(exc, Interrupted) else Interrupted()
            click.echo(f"interrupted by {stop.name}", err=True)
            sys.exit(stop.exit_code)


def _writable_folder(out: str | Path) -> Path:
    """``out``, created when missing; refused in one line when it cannot be written."""
    import tempfile

    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise InputError(f"cannot write the output folder {out}: {exc.strerror or exc}") from None
    return out


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="icefarm")
def main():
    """Grow icicles and glaze ice on any mesh, render them, and sweep parameters in batch.

    Start with `icefarm run MESH --size-m 0.3 -o out/` for one object, `icefarm params` for
    every parameter, and `icefarm sweep scenes/demo.yaml` for a whole sweep.
    """


def _assignments(values: tuple[str, ...]) -> dict:
    return dict(params.parse_assignment(v) for v in values)


def _box(text: str):
    """``--exclude``'s six numbers as a `icefarm.stages.drips.Box`."""
    from .stages.drips import Box

    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise InputError(f"--exclude takes xmin,ymin,zmin,xmax,ymax,zmax in meters, got {text!r}")
    return Box(tuple(v[:3]), tuple(v[3:]))


@main.command()
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float,
              help="Real height of the object's bounding box along gravity, in meters. Needed for OBJ, PLY, "
                   "STL and OFF (no units); USD and glTF/GLB files and the real-size generators keep their "
                   "own size without it, and are rescaled with it.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE",
              help="Override a parameter (repeatable); `icefarm params` lists them.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of the job.")
@click.option("-o", "--out", type=click.Path(file_okay=False), required=True,
              help="Folder that receives the job's artifacts.")
@click.option("--until", type=click.Choice(["water", "drips", "trajectories", "surface"]),
              help="Stop after this stage (default: all four stages, then the render).")
@click.option("--render", "render", default="preview", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ (preview, lookdev, final) or a YAML path.")
@click.option("--no-render", is_flag=True, help="Skip the scene files and the render.")
@click.option("--placement", type=click.Choice(PLACEMENTS), default="ground", show_default=True,
              help="ground: the object's lowest point rests on the ground (no ice on what it stands on, "
                   "icicles stop at the ground); hanging: a sign, a branch, a lamp, the ground below its ice.")
@click.option("--exclude", multiple=True, metavar="X0,Y0,Z0,X1,Y1,Z1",
              help="Keep icicles out of this box (meters, object centred on the origin); repeatable.")
@click.option("--cache", type=click.Path(file_okay=False),
              help="Stage cache folder to reuse results across runs (default: none).")
@click.option("--growth-frames", type=int, metavar="N",
              help="Also grow the ice over time: N frames (1-240) from the first drip to full growth, "
                   "each containing the one before (icicles lengthen, branches appear, bases and glaze "
                   "thicken), into OUT/growth/: ice_0001.ply..., frame_0001.png... (the job's render "
                   "config and camera), growth.mp4, growth.usda (time-sampled for DCCs) and frames.json. "
                   "Same as --set growth.frames=N.")
def run(mesh, size_m, assignments, seed, out, until, render, no_render, placement, exclude, cache, growth_frames):
    """Run one job on MESH (USD, glTF/GLB, any format trimesh reads, or generator:NAME) into OUT.

    Gravity follows the up axis of a USD or glTF file unless --set water.gravity=... says
    otherwise. Writes params.yaml (with the gravity used), water.ply (vertex colours: supply
    red, water blue), drips.json, trajectories.json, ice.ply, scene.xml/scene.pov,
    render.exr/png and timings.json.
    """
    from .asset_io import missing_size, with_asset_gravity
    from .pipeline import GENERATOR_PREFIX, JobSpec, Stage, run_job
    from .progress import ProgressMode

    values = _assignments(assignments)
    if growth_frames is not None:
        from .growth import MAX_FRAMES

        if not 1 <= growth_frames <= MAX_FRAMES:
            raise InputError(f"--growth-frames {growth_frames}: expected 1 to {MAX_FRAMES} frames")
        if until:
            raise InputError("--growth-frames needs the whole job: leave out --until")
        values["growth.frames"] = growth_frames
    if not mesh.startswith(GENERATOR_PREFIX):
        if not Path(mesh).is_file():
            raise InputError(f"mesh file not found: {mesh}")
        mesh = str(Path(mesh).resolve())
    if size_m is None and (why := missing_size(mesh)):
        raise InputError(f"{why}: pass the object's real height in meters with --size-m")
    resolved = params.resolve(with_asset_gravity(mesh, values))
    if not no_render:  # a bad config name fails now, in one line, not after the stages
        from .scene.config import load_render_config

        load_render_config(render)
        if Path(render).expanduser().is_file():
            render = str(Path(render).expanduser().resolve())
    spec = JobSpec(object_id=Path(mesh).stem, mesh=mesh, size_m=size_m, params=resolved, seed=seed,
                   render=None if no_render else render, exclude=tuple(_box(b) for b in exclude),
                   placement=placement)
    _writable_folder(out)
    if cache:
        _writable_folder(cache)
    outcome = run_job(spec, Path(out), Path(cache) if cache else None, Stage(until) if until else None,
                      progress=ProgressMode.for_stream(sys.stderr))
    if outcome.status is not JobState.DONE:
        click.echo(f"error: job failed {stage_phrase(outcome.failed_stage)}: {outcome.error} "
                   f"(details in {Path(out) / 'error.json'})", err=True)
        sys.exit(1)
    timings = read_job(Path(out)).stats
    for stage, seconds in outcome.seconds.items():
        click.echo(f"  {stage:<13} {seconds:8.3f} s")
    _print_plausibility(timings)
    if timings.get("growth_frames"):
        click.echo(f"  growth: {timings['growth_frames']} frames, {timings['growth_seconds_per_frame']:.2f} s "
                   f"per frame (surface and render): {Path(out) / 'growth'}")
    click.echo(f"done: {out}")


@main.command(name="render")
@click.argument("job_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--render", "render", default="final", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ (preview, lookdev, final) or a YAML path.")
@click.option("-o", "--out", type=click.Path(file_okay=False),
              help="Folder for the new scenes and images (default: JOB_DIR/renders/<config name>).")
def render_command(job_dir, render, out):
    """Render a finished job again with another render config, without recomputing it.

    For the contact-sheet cell worth a final frame: the job's object and ice get new
    scene.xml/scene.pov and renders in their own folder; the job folder is left as it is.
    """
    from .render_again import render_again

    out = Path(out) if out else Path(job_dir) / "renders" / Path(render).stem
    result = render_again(Path(job_dir), render, out, progress=sys.stderr.isatty())
    click.echo(f"  render        {result.seconds:8.3f} s ({result.variant}, {result.integrator})")
    click.echo(f"  scene         {result.scene_seconds:8.3f} s")
    if result.povray_seconds:
        click.echo(f"  povray        {result.povray_seconds:8.3f} s")
    click.echo(f"done: {out / result.files[0].name if result.files else out}")


@main.command(name="export")
@click.argument("job_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--format", "fmt", type=click.Choice(["glb", "usdz"]), default="glb", show_default=True,
              help="glb: binary glTF 2.0 for viewers and game engines; usdz: the job's scene.usda, "
                   "meshes and sky packed in one USD file.")
@click.option("-o", "--out", type=click.Path(dir_okay=False),
              help="The file to write (default: JOB_DIR/export/scene.<format>).")
def export_command(job_dir, fmt, out):
    """Export a job that rendered as one file: the object and the ice with their materials.

    Every such job already holds scene.usda (with object.usdc, ice.usdc): open it in usdview,
    Houdini, Maya, Omniverse, or Blender (File > Import > Universal Scene Description) for
    the cameras, the sun, the sky and the materials. This command writes a single file
    instead. In the GLB the ice refracts through the glTF extensions KHR_materials_transmission,
    KHR_materials_ior (1.31) and KHR_materials_volume (its absorption); glTF is +Y up, so
    the scene is turned to put minus gravity up. The USDZ keeps cameras and lights.

    \b
    The USD ice carries a MaterialX OpenPBR network beside its UsdPreviewSurface: Blender
    needs icefarm/dcc/blender_usd_hook.py (install it as an add-on) to import it as glass.
    USD camera apertures and focal lengths are in tenths of a scene unit (here meters):
    Maya's importer reads them as millimetres, which keeps the field of view but makes the
    film back 100 times smaller.
    """
    out = Path(out) if out else Path(job_dir) / "export" / f"scene.{fmt}"
    if fmt == "glb":
        from .gltf import write_glb as write
    else:
        from .usd import write_usdz as write
    click.echo(f"done: {write(Path(job_dir), out)}")


# A job whose icicles are fewer than this, or whose trunks are shorter than this (m), or whose
# glaze is thinner than this (mm) reads as bare at lookdev: the run summary says so.
FEW_ICICLES = 5
SHORT_TRUNK_M = 0.01
THIN_GLAZE_MM = 0.5


def _print_storm(timings: dict) -> None:
    """What a physical storm did, and one warning line when it left almost nothing visible."""
    kind = timings["storm_kind"].replace("_", " ")
    icicles, per_m = timings.get("icicles", 0), timings.get("icicles_per_m", 0.0)
    click.echo(f"  storm: {timings['storm_intensity']} {kind}, {timings['precipitation_mm']:.0f} mm of water: "
               f"glaze {timings['storm_glaze_p50_mm']:.1f} mm (p50 where the rain lands); {icicles} icicles, "
               f"{per_m:.0f} per m of drip rim ({timings.get('drip_rim_m', 0.0):.2f} m); the water: "
               f"{100 * timings['water_frozen']:.0f} % glaze, {100 * timings['water_shed']:.0f} % dripped, "
               f"{100 * timings['water_pooled']:.0f} % pooled")
    lengths = timings.get("trunk_lengths_m") or []
    longest = max([v for v in lengths if v is not None], default=0.0)
    if icicles < FEW_ICICLES or (lengths and longest < SHORT_TRUNK_M):
        size = "under 1 cm" if lengths and longest < SHORT_TRUNK_M else f"up to {100 * longest:.0f} cm"
        what = "no icicles" if icicles == 0 else f"{icicles} icicles {size}"
        click.echo(f"  warning: {what}: a {timings['storm_intensity']} storm on a small object or one with "
                   "little rim; try storm.intensity=severe or a larger size_m")
    elif timings["storm_glaze_p50_mm"] < THIN_GLAZE_MM:
        click.echo(f"  warning: glaze {timings['storm_glaze_p50_mm']:.1f} mm: too thin to read; raise "
                   "storm.precipitation or storm.freeze")


def _print_plausibility(timings: dict) -> None:
    if "upward_share" in timings:
        share, spread, cv = (timings.get(k) for k in ("upward_share", "branch_spread_mm", "length_cv"))
        click.echo(f"  trajectories: {'-' if share is None else f'{100 * share:.0f}'} % of segments upward "
                   f"(real: 0); branches spread {'-' if spread is None else f'{spread:.0f}'} mm from their "
                   f"parent; trunk lengths vary {'-' if cv is None else f'{100 * cv:.0f}'} % (std / mean)")
    if "storm_kind" in timings:
        _print_storm(timings)
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
               + ("none" if amplitude is None else f"{amplitude:.2f} mm deep, {ripple:.2f} cm apart")
               + " (real: 0.5-1 mm, about 1 cm apart, where the water is impure)")
    depth, corr, cv = (timings.get(k) for k in ("ripple_depth_mm", "ripple_correlation_3cm", "ripple_crest_cv"))
    if depth is not None and corr is not None and cv is not None:
        click.echo(f"  ripple texture on {timings.get('ripple_trunks', 0)} trunks of 10 cm and more: {depth:.2f} mm "
                   f"deep, radius 3 cm apart correlates {corr:.2f}, crest spacing varies {cv:.2f} (CV) "
                   "(natural: at most 0.6, and 0.1-0.35)")
    coverage = timings.get("glaze_coverage")
    if coverage is not None:
        p10, p50, p90, ratio = (timings.get(k) for k in ("glaze_p10_mm", "glaze_p50_mm", "glaze_p90_mm",
                                                        "glaze_top_bottom"))
        click.echo(f"  glaze: covers {100 * coverage:.1f} % of the wet surface, "
                   + ("-" if p50 is None else f"{p10:.1f} / {p50:.1f} / {p90:.1f} mm thick (p10/p50/p90)")
                   + ("" if ratio is None else f", top/bottom {ratio:.2f}"))
    gap = timings.get("ground_gap_mm")
    if gap is not None:
        click.echo(f"  ground: the object's lowest point {gap:.1f} mm above the ground plane"
                   + (" (stands on it)" if timings.get("placement") == "ground" else " (hanging)"))
    for key, what, real, fmt in (("taper", "taper (radius near the base / tip)", "a carrot: 3 and more", ".1f"),
                                 ("growth_ratio", "growth ratio (base - tip diameter) / length",
                                  "1/32-1/8, 0.03-0.13", ".3f"),
                                 ("profile_exponent", "profile exponent n of r - tip ~ d^n", "3/4", ".2f")):
        values = [v for v in timings.get(key) or [] if v is not None]  # None: too short to measure
        if values:
            click.echo(f"  {what}: median {statistics.median(values):{fmt}}, "
                       f"range {min(values):{fmt}}-{max(values):{fmt}} (real: {real})")


@main.command(name="params")
@click.option("--json", "as_json", is_flag=True, help="Print the table as JSON for scripts.")
def params_command(as_json):
    """List every parameter: group, name, the paper's symbol, unit, domain, default."""
    rows = params.table()
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    header = ("parameter", "symbol", "unit", "domain", "default")
    lines = [(f"{r['group']}.{r['name']}", r["symbol"], r["unit"], r["domain"], str(r["default"])) for r in rows]
    widths = [max(len(x[i]) for x in [header, *lines]) for i in range(len(header))]
    click.echo("  ".join(h.ljust(w) for h, w in zip(header, widths)))
    group = None
    for row, line in zip(rows, lines):
        if row["group"] != group:
            group = row["group"]
            click.echo(f"[{group}]")
        click.echo("  ".join(v.ljust(w) for v, w in zip(line, widths)) + "  " + row["doc"])
    from .stages.storm import constants

    click.echo("[constants of the storm model (icefarm.stages.storm)]")
    for c in constants():
        click.echo(f"{c.name:<24} {c.value:<10g} {c.unit:<7} {c.domain:<8} {c.source}")


@main.group()
def bench():
    """Benchmarks: medians over repeated runs (never run them as tests)."""


@bench.command(name="stages")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float, default=0.3, show_default=True, help="Object height in meters.")
@click.option("--drips", type=int, default=200, show_default=True, help="Drip points (drips.count).")
@click.option("--repeat", type=click.IntRange(min=1), default=7, show_default=True, help="Runs; the median is printed.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")
@click.option("--surface", is_flag=True, help="Also time stage 4 (the ice surface).")
def bench_stages(mesh, size_m, drips, repeat, assignments, surface):
    """Median seconds per stage on MESH (mesh loading excluded; the BVH build counts in water)."""
    from .bench import peak_memory_gb, stage_timings

    values = {"drips.count": drips, **_assignments(assignments)}
    runs = stage_timings(mesh, size_m, params.resolve(values), repeat, surface)
    click.echo(f"{mesh}: {runs.faces} faces, {runs.icicles} icicles, {repeat} runs (median, min)")
    for stage, samples in runs.seconds.items():
        click.echo(f"  {stage:<13} {statistics.median(samples):8.4f} s  {min(samples):8.4f} s")
    totals = [sum(v) for v in zip(*(runs.seconds[s] for s in ("water", "drips", "trajectories")))]
    click.echo(f"  {'stages 1-3':<13} {statistics.median(totals):8.4f} s  {min(totals):8.4f} s")
    if surface:
        rate = runs.ice_faces / statistics.median(runs.seconds["surface"])
        click.echo(f"  ice: {runs.ice_faces} faces, {rate:,.0f} faces/s")
    click.echo(f"  peak memory of this process: {peak_memory_gb():.2f} GB")


@bench.command(name="surface")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float, default=0.3, show_default=True, help="Object height in meters.")
@click.option("--drips", type=int, default=200, show_default=True, help="Drip points (drips.count).")
@click.option("--repeat", type=click.IntRange(min=1), default=5, show_default=True, help="Runs; the median is printed.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")
@click.pass_context
def bench_surface(ctx, mesh, size_m, drips, repeat, assignments):
    """Median seconds of all four stages on MESH, with ice faces per second."""
    ctx.invoke(bench_stages, mesh=mesh, size_m=size_m, drips=drips, repeat=repeat,
               assignments=assignments, surface=True)


@bench.command(name="proxy")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float, default=0.3, show_default=True, help="Object height in meters.")
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True, help="Runs; the median is printed.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")
def bench_proxy(mesh, size_m, repeat, assignments):
    """Median seconds to build the approximate surface (paper 5.1) of MESH."""
    from .mesh import prepare
    from .proxy import build_proxy

    p = params.resolve({"proxy.mode": "always", **_assignments(assignments)})
    prepared = prepare(mesh, size_m, p["water"]["gravity"])
    runs = [build_proxy(prepared.mesh, p["proxy"], prepared.problems) for _ in range(repeat)]
    click.echo(f"{mesh}: {prepared.problems.faces} faces, {prepared.problems.components} components")
    click.echo(f"  proxy: {runs[0].method.value}, {runs[0].faces} faces, {runs[0].components} component(s)")
    click.echo(f"  seconds: median {statistics.median(r.seconds for r in runs):.3f}, "
               f"min {min(r.seconds for r in runs):.3f} ({repeat} runs)")


@bench.command(name="render")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float, default=0.3, show_default=True, help="Object height in meters.")
@click.option("--drips", type=int, default=40, show_default=True, help="Drip points (drips.count).")
@click.option("--render", "render", default="lookdev", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ or a YAML path.")
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True, help="Timed runs; medians are printed.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")
def bench_render(mesh, size_m, drips, render, repeat, assignments):
    """Scene overhead against render time of one job on MESH (a file or generator:NAME).

    Runs the job once to fill the stage and kernel caches, then REPEAT more times with
    stages 1-4 cached, rendering each job's scene once more on its own: the scene overhead
    (writing scene.xml and the object, loading the scene, waiting for the POV-Ray files,
    which are written during the render) is compared with that render time.
    """
    from tqdm import tqdm

    from .bench import peak_memory_gb, render_timings
    from .pipeline import GENERATOR_PREFIX

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    p = params.resolve({"drips.count": drips, **_assignments(assignments)})
    with tqdm(total=repeat + 1, desc="render jobs", unit="job", leave=False) as bar:
        runs = render_timings(mesh, size_m, p, render, repeat, on_run=bar.update)
    med = statistics.median
    click.echo(f"{mesh}: {runs.ice_faces} ice faces, {render}, {runs.variant}, {repeat} runs (median, min)")
    for name, values in (("render step", runs.step), ("render", runs.render), ("render alone", runs.alone),
                         ("scene", runs.scene), ("  write", runs.write), ("  load", runs.load),
                         ("  wait", runs.wait)):
        click.echo(f"  {name:<13} {med(values):8.3f} s  {min(values):8.3f} s")
    for i, seconds in enumerate(zip(*runs.views)):
        click.echo(f"  view {i:<8} {med(seconds):8.3f} s  {min(seconds):8.3f} s")
    if any(runs.denoise):
        click.echo(f"  denoise       {med(runs.denoise):8.3f} s  {min(runs.denoise):8.3f} s  (in the views)")
    click.echo(f"  POV-Ray writer, CPU time during the render: {med(runs.povray_cpu):.3f} s")
    # Ratios within each run, then their median: the load of a shared machine drifts between runs.
    scene = [100 * s / a for s, a in zip(runs.scene, runs.alone)]
    step = [100 * (s - a) / a for s, a in zip(runs.step, runs.alone)]
    click.echo(f"  scene / render alone: {med(scene):.1f}% (target under 10%)")
    click.echo(f"  whole step beyond the render alone (scenes, images, the POV-Ray writer's share of the "
               f"CPU): {med(step):.1f}%")
    click.echo(f"  ice faces per second of render: {runs.ice_faces / med(runs.render):,.0f}; "
               f"peak memory of this process: {peak_memory_gb():.2f} GB")


@bench.command(name="growth")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--size-m", type=float, default=0.4, show_default=True, help="Object height in meters.")
@click.option("--drips", type=int, default=8, show_default=True, help="Drip points (drips.count).")
@click.option("--frames", type=click.IntRange(1, 240), default=4, show_default=True, help="Growth frames.")
@click.option("--render", "render", default="preview", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ or a YAML path; none for no render.")
@click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")
def bench_growth(mesh, size_m, drips, frames, render, assignments):
    """Seconds per growth frame against one full job's stage 4 and render, on MESH.

    Runs one job with FRAMES growth frames (stages 1-3 once; stage 4 and a render per
    frame) and prints the median frame's stage 4 and render next to the job's own.
    """
    from .bench import growth_timings
    from .pipeline import GENERATOR_PREFIX

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    p = params.resolve({"drips.count": drips, **_assignments(assignments)})
    runs = growth_timings(mesh, size_m, p, None if render == "none" else render, frames)
    med = statistics.median
    per_frame = [s + r for s, r in zip(runs.frame_surface, runs.frame_render)]
    click.echo(f"{mesh}: {runs.ice_faces} ice faces at full growth, {frames} frames, render {render} (median, max)")
    click.echo(f"  full job      surface {runs.surface:8.3f} s  render {runs.render:8.3f} s")
    click.echo(f"  per frame     surface {med(runs.frame_surface):8.3f} s  render {med(runs.frame_render):8.3f} s"
               f"  ({max(runs.frame_surface):.3f} s, {max(runs.frame_render):.3f} s at most)")
    click.echo(f"  seconds per frame: {med(per_frame):.3f} (whole growth step {runs.growth:.3f} s: "
               f"{runs.growth / frames:.3f} s per frame with measures, movie and USD)")


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--cell-width", type=int, default=320, show_default=True, help="Width of one cell in pixels.")
@click.option("--name", help="Sweep name for the header (default: from manifest.resolved.yaml or the folder).")
def sheet(run_dir, cell_width, name):
    """Build contact sheets (PNG and linear EXR, one per object) and sheets/index.html for RUN_DIR.

    RUN_DIR is a sweep folder (<out>/<sweep name>) as `icefarm sweep` writes it.
    """
    from .sheets import build_sheets

    results = build_sheets(Path(run_dir), cell_width, name)
    for r in results:
        click.echo(f"  {r.object_id}: {r.png} ({r.rows}x{r.cols}, {r.cells} cells, {r.failed} failed)")
    click.echo(f"gallery: {Path(run_dir) / 'sheets' / 'index.html'}")


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
def report(run_dir):
    """Write report.md and report.csv for RUN_DIR: the paper's Table 2 columns per job and object.

    Input polygons, icicles, ice polygons, seconds per stage and in total, render and proxy
    seconds and the render variant; stages taken from the cache show as "cached".
    """
    from .report import build_report

    for path in build_report(Path(run_dir)):
        click.echo(str(path))


@bench.command(name="table2")
@click.option("--meshes", type=click.Path(file_okay=False, path_type=Path),
              help="Folder of the test meshes (default: ../shared/meshes when it exists).")
@click.option("-o", "--out", type=click.Path(file_okay=False, path_type=Path), default=Path("out/table2"),
              show_default=True, help="Folder for table2.md and table2.csv.")
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True, help="Runs per row; medians are reported.")
@click.option("--rows", help="Only these rows of Table 2, e.g. a,c,e (default: all seven).")
def bench_table2(meshes, out, repeat, rows):
    """Reproduce the paper's Table 2 (Figure 16 a-g) side by side with its numbers.

    Each row runs on a real mesh decimated to the paper's polygon count, with the paper's
    icicle count and a voxel size calibrated to the paper's ice polygon count.
    """
    from .table2 import run_table2

    result = run_table2(meshes, out, repeat=repeat, rows=rows)
    click.echo(result.text)


def _after_sweep(summary) -> None:
    """Contact sheets and the timing report for a finished sweep (failed jobs included)."""
    from .report import build_report
    from .sheets import build_sheets

    if not any(r.job_dir and Path(r.job_dir).is_dir() for r in summary.jobs):
        return
    md, _ = build_report(summary.sweep_dir)
    click.echo(f"report: {md}")
    if any(Path(r.job_dir, "render.exr").is_file() for r in summary.jobs if r.job_dir):
        build_sheets(summary.sweep_dir)
        click.echo(f"sheets: {summary.sweep_dir / 'sheets' / 'index.html'}")


def _register_farm() -> None:
    from .farm.commands import bench_farm, make_sweep_command, validate

    main.add_command(validate)
    main.add_command(make_sweep_command(after=_after_sweep))
    bench.add_command(bench_farm, name="farm")


_register_farm()


if __name__ == "__main__":  # spawned farm workers re-import this module: run nothing then
    main()
