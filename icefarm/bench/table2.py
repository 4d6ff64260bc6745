"""Reproduce the paper's Table 2: the seven objects of its Figure 16, timed stage by stage.

Each row runs on a real mesh decimated (pymeshlab quadric edge collapse) to the paper's
polygon count, with the paper's number of icicles. The paper does not name its objects
except that 16(c)-(f) are Stanford models; `ROW_OBJECTS` states the mapping used here:

===  ==================  ===================================================================
a    cow.obj             Keenan Crane's cow: a small, clean, closed figurine
b    generator:fountain  the project's own fountain, after Kim et al.'s (the paper's 16 b)
c    dragon.obj          Stanford dragon
d    stanford-bunny.obj  Stanford bunny
e    armadillo.obj       Stanford armadillo
f    stanford-bunny.obj  Stanford bunny again, at the paper's higher polygon count
g    generator:roof      the project's house with overhanging eaves: room for 400 icicles
===  ==================  ===================================================================

Sizes are chosen per row (`RowObject.size_m`); glaze ice, which covers every wet surface
and so sets the polygon count, is off where the paper's count is low for its icicles
(all rows but c and e). The stages run as a job runs them (`icefarm.job.run_stages`: no icicle
hangs from the bottom ``drips.ground_clearance`` of a grounded object, icicles stop at the ground),
with the paper's relative storm and drip points (`PAPER_STAGES`: area-weighted, no spacing, none removed for want of
room or water) and no proxy (the rows are clean meshes). The ice polygon count is then steered towards the
paper's by the voxel size (marching-cubes faces grow as 1 / voxel**2): a coarse calibration run at the tip radius,
then rescaled runs until the count is within `CALIBRATION_TOLERANCE`. Stage times are
medians over repeated runs of the stage functions themselves (`icefarm.bench.timings.stage_timings`:
mesh loading excluded; the ray-tracing BVH build counts, in stage 1).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from .. import params as params_mod
from ..errors import InputError
from ..report import TABLE2_STAGES as STAGES
from .table2_rows import PAPER_TABLE2, ROW_OBJECTS, RowObject, Table2Row
from .table2_write import machine_info, table2_csv, table2_markdown
from .timings import stage_timings

CALIBRATION_TOLERANCE = 1.15  # stop calibrating once ice faces are within this factor of the target
CALIBRATION_RUNS = 5  # voxel sizes tried at most, the first one coarse
CALIBRATION_SEEDS = 3  # runs (seeds) per voxel size tried, at most the repeat count
MIN_VOXEL_M = 0.00012  # the finest voxel calibration may choose; the coarsest resolves the tip radius
# The paper's stage 2: drip points uniform over the drip region, however close or short; its
# Table 2 timed the stages on the models themselves (no approximate surface); nor does it
# smooth the glaze coat (a lookdev step of icefarm's, `glaze.smoothing`).
PAPER_STAGES = {"storm.mode": "relative", "trajectories.max_branches": 32, "trajectories.contact": "slide",
                "drips.distribution": "area", "drips.spacing": 0.0, "drips.min_fall": 0.0,
                "drips.min_length": 0.0, "proxy.mode": "never",
                "glaze.smoothing": 0, "glaze.runnels": 0.0}
MIN_SCALED_POLYGONS = 1000  # a reduced run keeps meshes fine enough for the water to find its way


class MeshUnavailable(LookupError):
    """A row's mesh is not available here; the row is skipped with this message."""


@dataclass(frozen=True)
class Table2Result:
    """What `run_table2` measured and wrote: rows run, rows skipped (key, reason), files."""

    rows: tuple
    skipped: tuple
    markdown_path: Path
    csv_path: Path
    text: str
    machine: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- inputs

def default_meshes_dir() -> Path | None:
    """``../shared/meshes`` seen from the working directory or from the repository root."""
    for root in (Path.cwd(), Path(__file__).resolve().parents[1]):
        candidate = root.parent / "shared" / "meshes"
        if candidate.is_dir():
            return candidate
    return None


def parse_rows(rows: Sequence[str] | str | None) -> list[str]:
    """Row keys in the paper's order; ``None`` means all seven.

    Raises
    ------
    InputError
        A key that is not one of a-g.
    """
    valid = [r.key for r in PAPER_TABLE2]
    if rows is None:
        return valid
    if isinstance(rows, str):
        rows = rows.split(",")
    keys = [str(r).strip().lower().strip("()") for r in rows if str(r).strip()]
    bad = [k for k in keys if k not in valid]
    if bad or not keys:
        raise InputError(f"table2 rows {','.join(bad) or '(none)'}: choose among {','.join(valid)} "
                         "(Figure 16 a-g), e.g. --rows a,b")
    return [k for k in valid if k in keys]


def decimate(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """Quadric edge-collapse decimation to ``faces`` triangles, topology and normals kept.

    A mesh with no more than ``faces`` faces comes back unchanged.
    """
    if faces < 4:
        raise ValueError(f"decimate: target of {faces} faces is too small")
    if len(mesh.faces) <= faces:
        return mesh
    from ..meshlab import current, meshset

    ms = meshset(mesh)
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(faces), preservenormal=True,
                                                preservetopology=True)
    return current(ms)


def generated_mesh(name: str, faces: int) -> trimesh.Trimesh:
    """The generator's mesh at the lowest detail that reaches ``faces`` faces (or its most)."""
    from ..generators import DEFAULT_DETAIL, MAX_DETAIL, generate

    reference = len(generate(name).faces)
    detail = int(np.clip(math.ceil(DEFAULT_DETAIL * math.sqrt(faces / reference)), 1, MAX_DETAIL))
    mesh = generate(name, detail)
    while len(mesh.faces) < faces and detail < MAX_DETAIL:  # face counts grow about as detail**2
        detail += 1
        mesh = generate(name, detail)
    while detail > 1:
        smaller = generate(name, detail - 1)
        if len(smaller.faces) < faces:
            break
        detail, mesh = detail - 1, smaller
    return mesh


def row_mesh(key: str, meshes_dir: Path | None, faces: int) -> trimesh.Trimesh:
    """The input mesh of row ``key`` with ``faces`` faces.

    Raises
    ------
    MeshUnavailable
        The row needs a mesh of the shared folder and it is not there.
    """
    obj = ROW_OBJECTS[key]
    if obj.generated:
        mesh = generated_mesh(obj.source.split(":", 1)[1], faces)
    else:
        if meshes_dir is None:
            raise MeshUnavailable(f"needs {obj.source} from the shared meshes folder; none found "
                                    "(give --meshes DIR)")
        path = Path(meshes_dir) / obj.source
        if not path.is_file():
            raise MeshUnavailable(f"needs {path}, which is missing")
        from ..mesh import load_mesh

        mesh = load_mesh(path)
    return decimate(mesh, faces)


# --------------------------------------------------------------------------- measuring

def _row_params(obj: RowObject, icicles: int, voxel_size: float) -> params_mod.Params:
    # The glaze keeps the defaults' voxel ratio (4 mm : 1 mm), so calibration steers glaze rows too.
    defaults = params_mod.defaults()
    ratio = defaults["glaze"]["voxel_size"] / defaults["surface"]["voxel_size"]
    return params_mod.resolve({**PAPER_STAGES, **dict(obj.settings)},
                              {"drips.count": icicles, "surface.voxel_size": voxel_size,
                               "glaze.voxel_size": ratio * voxel_size})


def calibrate_voxel(measure: Callable[[float], int], target: int, bounds: tuple[float, float],
                    runs: int = CALIBRATION_RUNS,
                    tolerance: float = CALIBRATION_TOLERANCE) -> tuple[float, int]:
    """The voxel size whose ice mesh has about ``target`` faces.

    Parameters
    ----------
    measure : callable
        Voxel size (m) to the number of ice faces it gives; an `InputError` (a grid too
        fine for the surface stage) makes the voxel coarser.
    target : int
        Wanted number of faces.
    bounds : (float, float)
        Smallest and largest voxel size allowed, in meters. The first run uses the largest:
        a coarse run is cheap, and the next ones step down from it.
    runs : int
        Measurements at most.
    tolerance : float
        Stop once the count is within this factor of ``target``.

    Returns
    -------
    (float, int)
        The voxel size whose count came nearest the target (in log ratio), and that count.
    """
    if target <= 0 or runs < 1 or not bounds[0] < bounds[1]:
        raise ValueError("calibrate_voxel: target and runs must be positive and bounds increasing")
    voxel = float(bounds[1])
    best: tuple[float, float, int] | None = None
    tried: set[float] = set()
    for _ in range(runs):
        tried.add(voxel)
        try:
            faces = measure(voxel)
        except InputError:  # the surface stage refuses a grid this fine
            voxel = float(np.clip(voxel * 1.5, *bounds))
            if voxel in tried:
                break
            continue
        miss = abs(math.log(max(faces, 1) / target))
        if best is None or miss < best[0]:
            best = (miss, voxel, faces)
        if miss <= math.log(tolerance):
            break
        # Faces grow as 1 / voxel**2; bounded steps for empty or near-empty meshes.
        step = math.sqrt(max(faces, 1) / target) if faces > 0 else 0.5
        voxel = float(np.clip(voxel * float(np.clip(step, 0.25, 4.0)), *bounds))
        if voxel in tried:  # pinned at a bound
            break
    if best is None:
        raise InputError(f"table2: no voxel size within {bounds[0]:g}-{bounds[1]:g} m gave an ice mesh")
    return best[1], best[2]


def measure_row(key: str, meshes_dir: Path | None, repeat: int, scale: float = 1.0,
                on_run: Callable[[], None] | None = None) -> Table2Row:
    """Build row ``key``'s mesh, calibrate its voxel size, time its stages ``repeat`` times.

    Raises
    ------
    MeshUnavailable
        The row's mesh is not available.
    """
    paper = next(r for r in PAPER_TABLE2 if r.key == key)
    obj = ROW_OBJECTS[key]
    faces = min(paper.polygons, max(MIN_SCALED_POLYGONS, round(paper.polygons * scale)))
    icicles = max(1, round(paper.icicles * scale))
    target = max(200, round(paper.ice_polygons * scale))
    mesh = row_mesh(key, meshes_dir, faces)

    def ice_faces(voxel: float) -> int:
        # The median over a few seeds: with few icicles one run's count varies by half.
        runs = stage_timings(mesh, obj.size_m, _row_params(obj, icicles, voxel), min(repeat, CALIBRATION_SEEDS),
                             surface=True)
        return round(statistics.median(runs.ice_faces_runs))

    coarsest = params_mod.defaults()["surface"]["tip_radius"]
    voxel, _ = calibrate_voxel(ice_faces, target, (MIN_VOXEL_M, coarsest))
    runs = stage_timings(mesh, obj.size_m, _row_params(obj, icicles, voxel), repeat, surface=True,
                         on_run=on_run)
    seconds = {stage: list(runs.seconds[stage]) for stage in STAGES}
    seconds["total"] = [sum(parts) for parts in zip(*(seconds[s] for s in STAGES))]
    ice = round(statistics.median(runs.ice_faces_runs))
    return Table2Row(paper, obj, runs.faces, runs.icicles, ice, target, voxel, seconds)


def run_table2(meshes_dir: Path | None, out_dir: Path, repeat: int = 3, rows: Sequence[str] | None = None,
               scale: float = 1.0, progress: bool = True) -> Table2Result:
    """Measure the paper's Table 2 rows and write ``table2.md`` and ``table2.csv`` into ``out_dir``.

    Parameters
    ----------
    meshes_dir : Path or None
        Folder of the shared test meshes; None looks for ``../shared/meshes``. Rows whose
        mesh is not found are skipped with the reason; the generated rows (b, g) always run.
    out_dir : Path
        Where the tables go (created).
    repeat : int
        Timed runs per row (after the calibration runs); medians are reported.
    rows : sequence of str, optional
        Row keys among a-g (or one comma-separated string); None runs all seven.
    scale : float
        In ]0, 1]: shrinks polygon, icicle and ice-polygon counts (a quick smoke run).
    progress : bool
        Show a tqdm bar over rows x repeats when stderr is a terminal.

    Raises
    ------
    InputError
        Bad rows, repeat or scale, or a ``meshes_dir`` that is not a folder.
    """
    keys = parse_rows(rows)
    if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
        raise InputError(f"table2: repeat must be a whole number >= 1, got {repeat!r}")
    if not (isinstance(scale, (int, float)) and 0 < scale <= 1):
        raise InputError(f"table2: scale must be in ]0, 1], got {scale!r}")
    if meshes_dir is None:
        meshes_dir = default_meshes_dir()
    elif not Path(meshes_dir).is_dir():
        raise InputError(f"table2: --meshes {meshes_dir} is not a folder; give the folder holding "
                         f"{', '.join(sorted({o.source for o in ROW_OBJECTS.values() if not o.generated}))}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    import sys

    from tqdm import tqdm

    bar = tqdm(total=len(keys) * repeat, unit="run", desc="table2", dynamic_ncols=True,
               disable=not (progress and sys.stderr.isatty()))
    machine = machine_info()
    measured: list[Table2Row] = []
    skipped: list[tuple[str, str]] = []
    try:
        for key in keys:
            bar.set_postfix_str(f"({key}) {ROW_OBJECTS[key].label}")
            try:
                measured.append(measure_row(key, meshes_dir, repeat, scale, on_run=lambda: bar.update(1)))
            except MeshUnavailable as exc:
                skipped.append((key, str(exc)))
                bar.update(repeat)
    finally:
        bar.close()
    machine_after = machine_info()
    text = table2_markdown(measured, skipped, repeat, scale, machine, machine_after)
    from ..artifacts import atomic_write

    md_path, csv_path = out_dir / "table2.md", out_dir / "table2.csv"
    atomic_write(md_path, text)
    atomic_write(csv_path, table2_csv(measured, skipped, repeat))
    return Table2Result(tuple(measured), tuple(skipped), md_path, csv_path, text,
                        {"before": machine, "after": machine_after})
