"""``icefarm bench``: benchmarks of the stages, the proxy, the render, growth and Table 2 (medians
over repeated runs; never run them as tests)."""

from __future__ import annotations

import statistics
from pathlib import Path

import click

from .. import params
from ..errors import InputError

# The options the benchmarks share.
MESH = click.argument("mesh", type=click.Path(dir_okay=False))
SET = click.option("--set", "assignments", multiple=True, metavar="GROUP.PARAM=VALUE", help="Override a parameter.")


def size_m_option(default: float):
    return click.option("--size-m", type=float, default=default, show_default=True, help="Object height in meters.")


def drips_option(default: int):
    return click.option("--drips", type=int, default=default, show_default=True, help="Drip points (drips.count).")


def repeat_option(default: int, help: str = "Runs; the median is printed."):
    return click.option("--repeat", type=click.IntRange(min=1), default=default, show_default=True, help=help)


@click.group()
def bench():
    """Benchmarks: medians over repeated runs (never run them as tests)."""


@bench.command(name="stages")
@MESH
@size_m_option(0.3)
@drips_option(200)
@repeat_option(7)
@SET
@click.option("--surface", is_flag=True, help="Also time stage 4 (the ice surface).")
def bench_stages(mesh, size_m, drips, repeat, assignments, surface):
    """Median seconds per stage on MESH (mesh loading excluded; the BVH build counts in water)."""
    from .timings import peak_memory_gb, stage_timings

    values = {"drips.count": drips, **params.parse_assignments(assignments)}
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
@MESH
@size_m_option(0.3)
@drips_option(200)
@repeat_option(5)
@SET
@click.pass_context
def bench_surface(ctx, mesh, size_m, drips, repeat, assignments):
    """Median seconds of all four stages on MESH, with ice faces per second."""
    ctx.invoke(bench_stages, mesh=mesh, size_m=size_m, drips=drips, repeat=repeat,
               assignments=assignments, surface=True)


@bench.command(name="proxy")
@MESH
@size_m_option(0.3)
@repeat_option(3)
@SET
def bench_proxy(mesh, size_m, repeat, assignments):
    """Median seconds to build the approximate surface (paper 5.1) of MESH."""
    from ..mesh import prepare
    from ..stages.proxy import build_proxy

    p = params.resolve({"proxy.mode": "always", **params.parse_assignments(assignments)})
    prepared = prepare(mesh, size_m, p.water.gravity)
    runs = [build_proxy(prepared.mesh, p.proxy, prepared.problems) for _ in range(repeat)]
    click.echo(f"{mesh}: {prepared.problems.faces} faces, {prepared.problems.components} components")
    click.echo(f"  proxy: {runs[0].method.value}, {runs[0].faces} faces, {runs[0].components} component(s)")
    click.echo(f"  seconds: median {statistics.median(r.seconds for r in runs):.3f}, "
               f"min {min(r.seconds for r in runs):.3f} ({repeat} runs)")


@bench.command(name="render")
@MESH
@size_m_option(0.3)
@drips_option(40)
@click.option("--render", "render", default="lookdev", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ or a YAML path.")
@repeat_option(3, "Timed runs; medians are printed.")
@SET
def bench_render(mesh, size_m, drips, render, repeat, assignments):
    """Scene overhead against render time of one job on MESH (a file or generator:NAME).

    Runs the job once to fill the stage and kernel caches, then REPEAT more times with
    stages 1-4 cached, rendering each job's scene once more on its own: the scene overhead
    (writing scene.xml and the object, loading the scene, waiting for the POV-Ray files,
    which are written during the render) is compared with that render time.
    """
    from tqdm import tqdm

    from ..job.pipeline import GENERATOR_PREFIX
    from .timings import peak_memory_gb, render_timings

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    p = params.resolve({"drips.count": drips, **params.parse_assignments(assignments)})
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


@bench.command(name="job")
@MESH
@click.option("--size-m", type=float, default=None,
              help="Object height in meters (needed for OBJ, PLY, STL and OFF; real-size generators and USD "
                   "or glTF files keep their own size without it).")
@click.option("--render", "render", default="lookdev", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ or a YAML path; none for no render.")
@click.option("--seed", type=int, default=0, show_default=True,
              help="The job's random seed, as `icefarm run --seed` takes it: it decides where the icicles hang, "
                   "so what the ice view frames and how long the render takes.")
@repeat_option(3, "Jobs run; medians are printed.")
@SET
def bench_job(mesh, size_m, render, seed, repeat, assignments):
    """Median seconds of each step of a whole job on MESH, as `icefarm run` runs it.

    Every run starts from nothing (no stage cache): the object's preparation, the four
    stages, the measures, the render and the USD export, each timed as the job's
    timings.json times it, with the job's wall-clock total and this process's peak memory.
    The USD export is written and the ice measured while Mitsuba renders: their own seconds
    are printed apart.
    The first run also compiles the render's kernels (Dr.Jit caches them on disk).
    """
    from tqdm import tqdm

    from ..asset_io import missing_size, with_asset_gravity
    from ..job.pipeline import GENERATOR_PREFIX
    from .timings import job_timings, peak_memory_gb

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    if size_m is None and (why := missing_size(mesh)):
        raise InputError(f"{why}: pass the object's real height in meters with --size-m")
    p = params.resolve(with_asset_gravity(mesh, params.parse_assignments(assignments)))
    with tqdm(total=repeat, desc="jobs", unit="job", leave=False) as bar:
        runs = job_timings(mesh, size_m, p, None if render == "none" else render, repeat, seed=seed,
                           on_run=bar.update)
    med = statistics.median
    jobs = f"{repeat} job" + ("s" if repeat != 1 else "")
    click.echo(f"{mesh}: {runs.ice_faces:,} ice faces, render {render}, seed {seed}, {jobs} (median, min)")
    for step, seconds in runs.steps.items():
        click.echo(f"  {step:<13} {med(seconds):8.3f} s  {min(seconds):8.3f} s")
    if runs.usd_write:
        click.echo(f"  {'usd beside':<13} {med(runs.usd_write):8.3f} s  {min(runs.usd_write):8.3f} s  "
                   "(written while Mitsuba rendered; the usd step is the wait after it)")
    if runs.measure_beside:
        click.echo(f"  {'measure beside':<13} {med(runs.measure_beside):8.3f} s  {min(runs.measure_beside):8.3f} s  "
                   "(taken while Mitsuba rendered; the measure step is the wait after it)")
    click.echo(f"  {'job':<13} {med(runs.total):8.3f} s  {min(runs.total):8.3f} s")
    click.echo(f"  peak memory of this process: {peak_memory_gb():.2f} GB")


@bench.command(name="sweep")
@click.argument("manifest", type=click.Path(dir_okay=False, exists=True))
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True, help="Local worker processes.")
@click.option("--backend", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="local: a process pool; dask: a LocalCluster of single-threaded workers.")
@repeat_option(3, "Sweeps run, each from nothing (a fresh folder and stage cache); the median is printed.")
@SET
def bench_sweep(manifest, workers, backend, repeat, assignments):
    """Median wall time of a whole sweep of MANIFEST (the README's demo: scenes/demo.yaml), as
    `icefarm sweep` runs it: its renders included, its stage cache starting empty every time.

    Prints each run's wall time (set-up excluded, as the sweep reports it), the median and the
    faces the jobs meshed. To compare two versions, alternate their runs on the same machine.
    """
    import tempfile

    from ..farm import SweepOptions, run_sweep
    from ..jobdir import read_job

    walls, faces = [], []
    for i in range(repeat):
        with tempfile.TemporaryDirectory(prefix="icefarm-bench-sweep-") as out:
            summary = run_sweep(manifest, out, SweepOptions(workers=workers, backend=backend, sets=assignments))
            if not summary.ok:
                failed = [r for r in summary.jobs if r.error]
                raise InputError(f"the benchmark sweep failed: {failed[0].error if failed else 'a job failed'}")
            walls.append(summary.wall_seconds)
            faces = [read_job(r.job_dir).stats.get("ice_faces", 0) for r in summary.jobs]
        click.echo(f"  run {i + 1}: {summary.done} jobs in {summary.wall_seconds:.1f} s")
    click.echo(f"{manifest}: {len(faces)} jobs on {workers} {backend} workers, median {statistics.median(walls):.1f} s "
               f"(min {min(walls):.1f} s); ice faces per job: median {statistics.median(faces):,.0f}, "
               f"max {max(faces):,}")


@bench.command(name="growth")
@MESH
@size_m_option(0.4)
@drips_option(8)
@click.option("--frames", type=click.IntRange(1, 240), default=4, show_default=True, help="Growth frames.")
@click.option("--render", "render", default="preview", show_default=True, metavar="CONFIG",
              help="Render config: a name in render_configs/ or a YAML path; none for no render.")
@SET
def bench_growth(mesh, size_m, drips, frames, render, assignments):
    """Seconds per growth frame against one full job's stage 4 and render, on MESH.

    Runs one job with FRAMES growth frames (stages 1-3 once; stage 4 and a render per
    frame) and prints the median frame's stage 4 and render next to the job's own.
    """
    from ..job.pipeline import GENERATOR_PREFIX
    from .timings import growth_timings

    if not mesh.startswith(GENERATOR_PREFIX) and not Path(mesh).is_file():
        raise InputError(f"mesh file not found: {mesh}")
    p = params.resolve({"drips.count": drips, **params.parse_assignments(assignments)})
    runs = growth_timings(mesh, size_m, p, None if render == "none" else render, frames)
    med = statistics.median
    per_frame = [s + r for s, r in zip(runs.frame_surface, runs.frame_render)]
    click.echo(f"{mesh}: {runs.ice_faces} ice faces at full growth, {frames} frames, render {render} (median, max)")
    click.echo(f"  full job      surface {runs.surface:8.3f} s  render {runs.render:8.3f} s")
    click.echo(f"  per frame     surface {med(runs.frame_surface):8.3f} s  render {med(runs.frame_render):8.3f} s"
               f"  ({max(runs.frame_surface):.3f} s, {max(runs.frame_render):.3f} s at most)")
    click.echo(f"  seconds per frame: {med(per_frame):.3f} (whole growth step {runs.growth:.3f} s: "
               f"{runs.growth / frames:.3f} s per frame with measures, movie and USD)")


@bench.command(name="table2")
@click.option("--meshes", type=click.Path(file_okay=False, path_type=Path),
              help="Folder of the test meshes (default: ../shared/meshes when it exists).")
@click.option("-o", "--out", type=click.Path(file_okay=False, path_type=Path), default=Path("out/table2"),
              show_default=True, help="Folder for table2.md and table2.csv.")
@click.option("--repeat", type=click.IntRange(min=1), default=3, show_default=True,
              help="Runs per row; medians are reported.")
@click.option("--rows", help="Only these rows of Table 2, e.g. a,c,e (default: all seven).")
def bench_table2(meshes, out, repeat, rows):
    """Reproduce the paper's Table 2 (Figure 16 a-g) side by side with its numbers.

    Each row runs on a real mesh decimated to the paper's polygon count, with the paper's
    icicle count and a voxel size calibrated to the paper's ice polygon count.
    """
    from .table2 import run_table2

    result = run_table2(meshes, out, repeat=repeat, rows=rows)
    click.echo(result.text)
