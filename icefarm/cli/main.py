"""The ``icefarm`` command line."""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import click

from .. import __version__, params
from ..bench.commands import bench
from ..errors import InputError, Interrupted, cannot_write, one_line_each
from ..jobdir import (
    ERROR,
    EXPORT_DIR,
    FRAMES,
    GROWTH_DIR,
    GROWTH_MP4,
    GROWTH_USDA,
    MANIFEST,
    RENDER_EXR,
    RENDERS_DIR,
    SCENE_USDA,
    SHEETS_DIR,
    JobState,
    growth_frame,
    growth_ice,
    read_job,
    stage_phrase,
)
from ..placement import PLACEMENTS
from .options import exclusion_box, readable_cache, writable_folder
from .summary import print_job_summary


class _Group(click.Group):
    """Turns `InputError` into one clean line and exit status 2 instead of a traceback, and
    a write that failed (a full disk) into one line and status 1; Ctrl-C exits 130 (128 + the
    signal), not 1 like a failed job."""

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
        except OSError as exc:  # a full disk, a folder made read-only while rendering or exporting
            click.echo(one_line_each(f"error: {cannot_write(exc, exc.filename or 'a file')}"), err=True)
            sys.exit(1)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="icefarm")
def main():
    """Grow icicles and glaze ice on any mesh, render them, and sweep parameters in batch.

    Start with `icefarm run MESH --size-m 0.3 -o out/` for one object, `icefarm params` for
    every parameter, and `icefarm sweep scenes/demo.yaml` for a whole sweep.
    """


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
              help="Folder that receives the job's artifacts. One that holds an earlier job is first cleared "
                   "of that job's files (its renders/ and export/ too); other files stay.")
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
              help="Stage cache folder to reuse results across runs (default: none). A shared cache this "
                   "user may only read is read: its results are reused, the others computed and not stored.")
@click.option("--growth-frames", type=int, metavar="N",
              help="Also grow the ice over time: N frames (1-240) from the first drip to full growth, "
                   "each containing the one before (icicles lengthen, branches appear, bases and glaze "
                   f"thicken), into OUT/{GROWTH_DIR}/: {growth_ice(1)}..., {growth_frame(1)}... (the job's render "
                   f"config and camera), {GROWTH_MP4}, {GROWTH_USDA} (time-sampled for DCCs) and {FRAMES}. "
                   "Same as --set growth.frames=N.")
def run(mesh, size_m, assignments, seed, out, until, render, no_render, placement, exclude, cache, growth_frames):
    """Run one job on MESH (USD, glTF/GLB, any format trimesh reads, or generator:NAME) into OUT.

    Gravity follows the up axis of a USD or glTF file unless --set water.gravity=... says
    otherwise. Writes params.yaml (with the gravity used), water.ply (vertex colours: supply
    red, water blue), drips.json, trajectories.json, ice.ply, scene.xml/scene.pov,
    render.exr/png and timings.json.
    """
    from ..api import job_spec
    from ..asset_io import missing_size
    from ..job.pipeline import GENERATOR_PREFIX, Stage, run_job
    from ..progress import ProgressMode

    values = params.parse_assignments(assignments)
    if growth_frames is not None:
        from ..stages.growth import MAX_FRAMES

        if not 1 <= growth_frames <= MAX_FRAMES:
            raise InputError(f"--growth-frames {growth_frames}: expected 1 to {MAX_FRAMES} frames")
        if until:
            raise InputError("--growth-frames needs the whole job: leave out --until")
        values["growth.frames"] = growth_frames
    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    if size_m is None and (why := missing_size(mesh)):
        raise InputError(f"{why}: pass the object's real height in meters with --size-m")
    if size_m is not None and not (math.isfinite(size_m) and size_m > 0):
        raise InputError(f"--size-m {size_m:g}: the object's real height in meters is a number above 0")
    with warnings.catch_warnings(record=True) as said:  # the API warns; the command line says
        warnings.simplefilter("always", UserWarning)
        spec = job_spec(mesh, size_m=size_m, params=values, seed=seed, placement=placement,
                        exclude=[exclusion_box(b) for b in exclude], render=None if no_render else render)
    for warning in said:
        click.echo(f"warning: {warning.message}", err=True)
    writable_folder(out)
    if cache:
        readable_cache(cache)
    outcome = run_job(spec, Path(out), Path(cache) if cache else None, Stage(until) if until else None,
                      progress=ProgressMode.for_stream(sys.stderr))
    if outcome.status is not JobState.DONE:
        click.echo(f"error: job failed {stage_phrase(outcome.failed_stage)}: {outcome.error} "
                   f"(details in {Path(out) / ERROR})", err=True)
        sys.exit(1)
    timings = read_job(Path(out)).stats
    for stage, seconds in outcome.seconds.items():
        click.echo(f"  {stage:<13} {seconds:8.3f} s")
    print_job_summary(timings)
    if timings.get("growth_frames"):
        click.echo(f"  growth: {timings['growth_frames']} frames, {timings['growth_seconds_per_frame']:.2f} s "
                   f"per frame (surface and render): {Path(out) / 'growth'}")
    click.echo(f"done: {out}")


@main.command(name="render")
@click.argument("job_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--render", "render", default="lookdev", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ (preview, lookdev, final) or a YAML path. "
                   "final is 1920x1080 at 512 spp: many minutes on a few cores.")
@click.option("-o", "--out", type=click.Path(file_okay=False),
              help="Folder for the new scenes and images (default: JOB_DIR/renders/<config name>); an "
                   "earlier render there is replaced.")
def render_command(job_dir, render, out):
    """Render a finished job again with another render config, without recomputing it.

    For the contact-sheet cell worth a final frame: the job's object and ice get new
    scene.xml/scene.pov and renders in their own folder; the job folder is left as it is.
    Says first how long it expects the render to take (from the job's own render), prints
    progress lines when its output is not a terminal, and leaves INCOMPLETE.txt in the
    folder until the render is done.
    """
    from ..export import RENDER_FILES, estimate_seconds, meshed_coarser, render_again
    from ..scene.config import load_render_config

    out = Path(out) if out else Path(job_dir) / RENDERS_DIR / Path(render).stem
    config = load_render_config(render)
    coarser = meshed_coarser(Path(job_dir), config)
    if coarser:
        click.echo(f"note: {coarser}")
    estimate = estimate_seconds(Path(job_dir), config)
    if estimate is not None:
        seconds, basis = estimate
        took = f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"
        click.echo(f"render {config.name}: {config.width}x{config.height} at {config.spp} spp x "
                   f"{len(config.views)} view{'s' * (len(config.views) != 1)}, about {took} ({basis})")
    if any((out / name).is_file() for name in RENDER_FILES):
        click.echo(f"replacing the earlier render in {out}")
    tty = sys.stdout.isatty()
    result = render_again(Path(job_dir), render, out, progress=sys.stderr.isatty(),
                          report=None if tty else lambda line: click.echo(f"  render: {line}"))
    click.echo(f"  render        {result.seconds:8.3f} s ({result.variant}, {result.integrator})")
    click.echo(f"  scene         {result.scene_seconds:8.3f} s")
    if result.povray_seconds:
        click.echo(f"  povray        {result.povray_seconds:8.3f} s")
    click.echo(f"done: {out / result.files[0].name if result.files else out}")


@main.command(name="export")
@click.argument("job_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--format", "fmt", type=click.Choice(["glb", "usdz"]), default="glb", show_default=True,
              help=f"glb: binary glTF 2.0 for viewers and game engines; usdz: the job's {SCENE_USDA}, "
                   "meshes and sky packed in one USD file.")
@click.option("-o", "--out", type=click.Path(dir_okay=False),
              help=f"The file to write (default: JOB_DIR/{EXPORT_DIR}/scene.<format>).")
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
    out = Path(out) if out else Path(job_dir) / EXPORT_DIR / f"scene.{fmt}"
    if fmt == "glb":
        from ..export.gltf import write_glb as write
    else:
        from ..export.usd import write_usdz as write
    click.echo(f"done: {write(Path(job_dir), out)}")


@main.group(name="dcc")
def dcc_group():
    """Tools for the DCCs: the Blender add-on."""


@dcc_group.command(name="blender-addon")
@click.option("-o", "--out", type=click.Path(dir_okay=False), default="icefarm_blender.zip", show_default=True,
              help="The zip to write.")
def blender_addon_command(out):
    """Write the Blender add-on as a zip: in Blender, Edit > Preferences > Add-ons, Install from
    Disk, pick it and enable "icefarm"; a panel in the 3D view's sidebar (N) grows ice on the
    selected objects by running this icefarm (name its executable in the add-on's preferences)."""
    from ..dcc.addon_zip import write_blender_addon

    click.echo(f"done: {write_blender_addon(out)}")


@main.command(name="params")
@click.option("--json", "as_json", is_flag=True, help="Print the table as JSON for scripts.")
def params_command(as_json):
    """List every parameter: group, name, the paper's symbol, unit, domain, default, and the
    storm.mode that reads it (physical: the storm in real units, the default; relative: the
    paper's knobs, relative to the object; both)."""
    rows = params.table()
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    header = ("parameter", "symbol", "unit", "domain", "default", "mode")
    lines = [(f"{r['group']}.{r['name']}", r["symbol"], r["unit"], r["domain"], str(r["default"]), r["mode"])
             for r in rows]
    widths = [max(len(x[i]) for x in [header, *lines]) for i in range(len(header))]
    click.echo("  ".join(h.ljust(w) for h, w in zip(header, widths)))
    group = None
    for row, line in zip(rows, lines):
        if row["group"] != group:
            group = row["group"]
            click.echo(f"[{group}]")
        click.echo("  ".join(v.ljust(w) for v, w in zip(line, widths)) + "  " + row["doc"])
    from ..stages.icicle_size import constants as icicle_constants
    from ..stages.storm import constants

    for title, listed in (("the storm model (icefarm.stages.storm)", constants()),
                          ("the icicles' sizes and fringe (icefarm.stages.icicle_size, rims)", icicle_constants())):
        click.echo(f"[constants of {title}]")
        for c in listed:
            click.echo(f"{c.name:<27} {c.value:<10g} {c.unit:<7} {c.domain:<8} {c.source}")


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--cell-width", type=int, default=320, show_default=True, help="Width of one cell in pixels.")
@click.option("--name", help=f"Sweep name for the header (default: from {MANIFEST} or the folder).")
def sheet(run_dir, cell_width, name):
    """Build contact sheets (PNG and linear EXR, one per object) and sheets/index.html for RUN_DIR.

    RUN_DIR is a sweep folder (<out>/<sweep name>) as `icefarm sweep` writes it.
    """
    from ..sheets import build_sheets

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
    from ..report import build_report

    for path in build_report(Path(run_dir)):
        click.echo(str(path))


def _after_sweep(summary) -> None:
    """Contact sheets and the timing report for a finished sweep (failed jobs included)."""
    from ..report import build_report
    from ..sheets import build_sheets

    if not any(r.job_dir and Path(r.job_dir).is_dir() for r in summary.jobs):
        return
    md, _ = build_report(summary.sweep_dir)
    click.echo(f"report: {md}")
    if any(Path(r.job_dir, RENDER_EXR).is_file() for r in summary.jobs if r.job_dir):
        build_sheets(summary.sweep_dir)
        click.echo(f"sheets: {summary.sweep_dir / SHEETS_DIR / 'index.html'}")


def _register_farm() -> None:
    from ..farm.commands import bench_farm, make_sweep_command, validate

    main.add_command(validate)
    main.add_command(make_sweep_command(after=_after_sweep))
    bench.add_command(bench_farm, name="farm")


main.add_command(bench)
_register_farm()


if __name__ == "__main__":  # spawned farm workers re-import this module: run nothing then
    main()
