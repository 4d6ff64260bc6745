"""The job folder and the sweep folder: every file icefarm writes there, what it holds, and how
the records read back, in one place.

Every name below is a constant of this module; other modules use the constants (a test, the
layout test, holds them to at most three literals elsewhere). The pipeline (`icefarm.job.pipeline`)
writes a job's folder; the sweep, the report, the contact sheets, the exporters and the CLI
read it back through `read_job`, `check_done`, `read_views` and `scan_sweep`.

**A job folder** (``OUT/<sweep>/jobs/<object id>/<job id>/`` in a sweep, ``-o`` of
``icefarm run``):

- ``params.yaml`` (`PARAMS`): the resolved parameters the job ran with, by group.
- ``proxy.ply`` (`PROXY`): the approximate surface the water ran on, for problem meshes only.
- ``water.ply`` (`WATER`): stage 1 on the flow mesh, vertex properties ``supply`` and ``water``,
  coloured (supply red, water a blue ramp).
- ``drips.json`` (`DRIPS`), ``trajectories.json`` (`TRAJECTORIES`): stages 2 and 3;
  ``landing.json`` (`LANDING`): where the water off the tips lands, with ground ice.
- ``ice.ply`` (`ICE`): the ice, watertight, meters (stage 4).
- The scene, with a render config: ``scene.json`` (`SCENE_SPEC`: the renderer-agnostic
  scene, `icefarm.scene.spec`), written from it ``scene.xml`` (`SCENE_XML`, Mitsuba 3) and
  ``scene.pov`` (`SCENE_POV`, POV-Ray 3.7) with ``object.inc`` and ``ice.inc`` (`OBJECT_INC`,
  `ICE_INC`), ``object.ply`` (`OBJECT`: the object as rendered, split along creases, with
  its normals), the sky image (`sky_name`), and ``views.json`` (`VIEWS`: per view its
  index, name, frame, image stem and how wide its densest icicles are, `write_views`).
- The renders: ``render.exr`` (linear) and ``render.png`` (sRGB) for the main view
  (`RENDER_EXR`, `RENDER_PNG`), ``render_view<i>.*`` for the others (`view_stem`), and
  ``render_povray.png`` / ``render_povray_view<i>.png`` (`POVRAY_STEM`) from POV-Ray.
- For DCCs: ``scene.usda`` (`SCENE_USDA`) referencing ``object.usdc`` and ``ice.usdc``
  (`OBJECT_USDC`, `ICE_USDC`). For a USD input, rendered or not: ``ice_layer.usda``
  (`ICE_LAYER`), the ice over the asset's own file (`icefarm.export.ice_layer`), its mesh
  in ``ice.usdc``.
- ``growth/`` (`GROWTH_DIR`), with ``growth.frames``: per frame ``ice_0001.ply`` ... and
  ``frame_0001.png`` ... (`growth_ice`, `growth_frame`), ``growth.mp4`` (`GROWTH_MP4`),
  ``growth.usda`` (`GROWTH_USDA`) with its value clips ``ice_0001.usdc`` ... (`growth_clip`)
  and their manifest ``ice_manifest.usda`` (`GROWTH_MANIFEST`), and ``frames.json``
  (`FRAMES`: each frame's fraction, ice and figures).
- ``timings.json`` (`TIMINGS`): each step's seconds, what came from the stage cache, and the
  job's figures (icicles, ice faces, plausibility measures, the render's variant).
- ``done.json`` (`DONE`), written last and atomically: the job finished; it repeats
  ``timings.json`` and lists every file above with its size and sha256 (`check_done`).
  ``error.json`` (`ERROR`) instead: the failed step, its message and traceback.
- Added later, not listed in ``done.json`` (`LATER`): ``renders/`` (`RENDERS_DIR`,
  ``icefarm render``) and ``export/`` (`EXPORT_DIR`, ``icefarm export``).

**A sweep folder** (``OUT/<sweep name>/``): ``manifest.resolved.yaml`` (`MANIFEST`: the
manifest as run, with its jobs), ``jobs/`` (`JOBS_DIR`: one job folder per job),
``jobs.csv`` (`JOBS_CSV`: one row per job, its swept values, status and seconds),
``cache/`` (`CACHE_DIR`: the stage cache), ``report.md`` and ``report.csv`` (`REPORT_MD`,
`REPORT_CSV`) and ``sheets/`` (`SHEETS_DIR`: contact sheets and the gallery).
`scan_sweep` finds its job folders in one order for every reader.
"""

from __future__ import annotations

import csv
import enum
import hashlib
import json
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .params import flatten
from .yaml_io import load_yaml

# ---------------------------------------------------------------- the job folder's files
PARAMS = "params.yaml"      # the resolved parameters the job ran with
PROXY = "proxy.ply"
WATER = "water.ply"
DRIPS = "drips.json"
TRAJECTORIES = "trajectories.json"
LANDING = "landing.json"
ICE = "ice.ply"
# ice.ply's per-vertex float property: how far under a ripple crest, 0 to 1 (milky bands).
# Mitsuba reads it as the mesh attribute "vertex_crest": it takes "NAME_x" for a component.
ICE_BANDS = "crest_x"
OBJECT = "object.ply"
SCENE_SPEC = "scene.json"
SCENE_XML = "scene.xml"
SCENE_POV = "scene.pov"
OBJECT_INC = "object.inc"
ICE_INC = "ice.inc"
VIEWS = "views.json"
RENDER_STEM = "render"
RENDER_EXR = f"{RENDER_STEM}.exr"
RENDER_PNG = f"{RENDER_STEM}.png"
POVRAY_STEM = f"{RENDER_STEM}_povray"
SCENE_USDA = "scene.usda"
OBJECT_USDC = "object.usdc"
ICE_USDC = "ice.usdc"
ICE_LAYER = "ice_layer.usda"  # the ice composed over a USD input's own file
GROWTH_DIR = "growth"
FRAMES = "frames.json"
GROWTH_MP4 = "growth.mp4"
GROWTH_USDA = "growth.usda"
GROWTH_MANIFEST = "ice_manifest.usda"
GROWTH_CLIPS = "ice_*.usdc"  # every growth clip, for clearing old ones
GROWTH_ICE_USDC = "growth_ice.usdc"  # growth's one layer before value clips, cleared too
GROWTH_SCRATCH = ".scene"  # where each growth frame's scene is written and rendered, removed after
TIMINGS = "timings.json"    # {"seconds": {step: s}, "reused": [...], ...figures}
DONE = "done.json"          # written last, atomically: the job finished
ERROR = "error.json"        # {"stage", "message", "traceback", "seconds"}: the job failed
RENDERS_DIR = "renders"
EXPORT_DIR = "export"
LATER = (RENDERS_DIR, EXPORT_DIR)  # added after the job, not listed in done.json
RECORDS = (DONE, ERROR, TIMINGS, PARAMS)  # a folder with any of them is a job folder

# ---------------------------------------------------------------- the sweep folder's files
MANIFEST = "manifest.resolved.yaml"
JOBS_DIR = "jobs"
JOBS_CSV = "jobs.csv"
CACHE_DIR = "cache"
REPORT_MD = "report.md"
REPORT_CSV = "report.csv"
SHEETS_DIR = "sheets"

#: The files of a job folder (not the sweep folder's).
JOB_FILES = (PARAMS, PROXY, WATER, DRIPS, TRAJECTORIES, LANDING, ICE, OBJECT, SCENE_SPEC, SCENE_XML, SCENE_POV,
             OBJECT_INC, ICE_INC, VIEWS, RENDER_EXR, RENDER_PNG, SCENE_USDA, OBJECT_USDC, ICE_USDC, ICE_LAYER,
             TIMINGS, DONE, ERROR)

#: Every file name above, for the test that keeps them out of other modules.
FILE_NAMES = (PARAMS, PROXY, WATER, DRIPS, TRAJECTORIES, LANDING, ICE, OBJECT, SCENE_SPEC, SCENE_XML, SCENE_POV,
              OBJECT_INC, ICE_INC, VIEWS, RENDER_EXR, RENDER_PNG, f"{POVRAY_STEM}.png", SCENE_USDA, OBJECT_USDC,
              ICE_USDC, ICE_LAYER, FRAMES, GROWTH_MP4, GROWTH_USDA, GROWTH_MANIFEST, GROWTH_ICE_USDC, TIMINGS, DONE,
              ERROR, MANIFEST, JOBS_CSV, REPORT_MD, REPORT_CSV)


def view_stem(index: int, prefix: str = RENDER_STEM) -> str:
    """File stem of view ``index``: ``render`` for the main view, ``render_view<i>`` after
    (``prefix`` `POVRAY_STEM` for POV-Ray's)."""
    return prefix if index == 0 else f"{prefix}_view{index}"


def sky_name(sky: str, azimuth: float, elevation: float) -> str:
    """The sky image's name in a job folder: ``sky_az<a>_el<e>.exr`` for the procedural sky
    (named by what it depends on), ``sky_<stem><suffix>`` for a copied image ``sky``."""
    if sky == "procedural":
        return f"sky_az{azimuth:g}_el{elevation:g}.exr"
    source = Path(sky)
    return f"sky_{source.stem}{source.suffix.lower()}"


def growth_ice(index: int) -> str:
    """Growth frame ``index``'s (from 1) ice mesh."""
    return f"ice_{index:04d}.ply"


def growth_frame(index: int) -> str:
    """Growth frame ``index``'s image."""
    return f"frame_{index:04d}.png"


def growth_clip(index: int) -> str:
    """Growth frame ``index``'s ice as a USD value clip."""
    return f"ice_{index:04d}.usdc"


def total_seconds(seconds: Any) -> float | None:
    """Sum of a job's recorded step times (``timings.json``'s or ``error.json``'s ``seconds``:
    preparation, proxy, stages with their cache loads, render, export); None when it holds
    no number. Booleans are not seconds."""
    if not isinstance(seconds, Mapping):
        return None
    values = [float(v) for v in seconds.values() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return sum(values) if values else None


def stage_phrase(stage: str | None) -> str:
    """Where a job failed, for a sentence: ``in stage surface``, or ``after stage
    trajectories`` for a failure between steps (the pipeline records ``after <step>``)."""
    if not stage:
        return "in an unknown stage"
    return f"after stage {stage[6:]}" if stage.startswith("after ") else f"in stage {stage}"


def error_line(message: Any, default: str = "-") -> str:
    """The line that stands for a failure in tables and cells: the first non-empty line of
    its message, which names the exception (``ValueError: ...``) where the pipeline wrote
    it; later lines are detail."""
    for line in str(message or "").splitlines():
        if line.strip():
            return line.strip()
    return default


class JobState(str, enum.Enum):
    """A job's state, as every reader tells it (and as jobs.csv and the report write it)."""

    DONE = "done"        # done.json: finished
    FAILED = "failed"    # error.json without done.json
    PENDING = "pending"  # neither: not started, running, or killed


@dataclass(frozen=True)
class JobFolder:
    """One job folder as it reads back (`read_job`); missing or damaged files read as empty.

    Attributes
    ----------
    path : Path
    state : JobState
    seconds : dict
        Step name to seconds, as timings.json (or, for a failed job, error.json) recorded them.
    reused : tuple of str
        Steps taken from the stage cache.
    stats : dict
        The rest of timings.json: input faces, icicles, ice faces, plausibility figures,
        the render's variant and seconds.
    params : dict or None
        Flat ``{"group.name": value}`` from params.yaml; None when it is missing or unreadable.
    failed_stage, message, traceback : str or None
        From error.json.
    """

    path: Path
    state: JobState
    seconds: dict[str, Any] = field(default_factory=dict)
    reused: tuple[str, ...] = ()
    stats: dict[str, Any] = field(default_factory=dict)
    params: dict[str, Any] | None = None
    failed_stage: str | None = None
    message: str | None = None
    traceback: str | None = None

    @property
    def object_id(self) -> str:
        return self.path.parent.name or "-"

    @property
    def job_id(self) -> str:
        return self.path.name

    @property
    def total_seconds(self) -> float | None:
        return total_seconds(self.seconds)


def job_state(job_dir: Path) -> JobState:
    """DONE when done.json is there, FAILED when only error.json is, PENDING otherwise."""
    job_dir = Path(job_dir)
    if (job_dir / DONE).is_file():
        return JobState.DONE
    return JobState.FAILED if (job_dir / ERROR).is_file() else JobState.PENDING


def read_job(job_dir: Path) -> JobFolder:
    """Read one job folder: its state, seconds, figures, parameters and failure."""
    job_dir = Path(job_dir)
    state = job_state(job_dir)
    params = _read_params(job_dir / PARAMS)
    if state is JobState.DONE:
        # A done job always has timings.json; done.json carries a copy of it.
        timings = read_json(job_dir / TIMINGS) or read_json(job_dir / DONE)
        return JobFolder(job_dir, state, _mapping(timings.get("seconds")),
                         tuple(str(s) for s in timings.get("reused") or ()),
                         {k: v for k, v in timings.items() if k not in ("seconds", "reused", "job", "artifacts")},
                         params)
    if state is JobState.FAILED:
        error = read_json(job_dir / ERROR)
        return JobFolder(job_dir, state, _mapping(error.get("seconds")), (), {}, params,
                         str(error.get("stage") or "-"), str(error.get("message") or "unreadable error.json"),
                         str(error["traceback"]) if error.get("traceback") else None)
    return JobFolder(job_dir, state, params=params)


def read_json(path: Path) -> dict[str, Any]:
    """A JSON object from ``path``; empty when missing, unreadable or not an object."""
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def _read_params(path: Path) -> dict[str, Any] | None:
    try:
        data = load_yaml(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return flatten(data) if isinstance(data, Mapping) else None


def _mapping(value: Any) -> dict[str, Any]:
    return dict(value) if isinstance(value, Mapping) else {}


# ---------------------------------------------------------------- done.json's check
def file_digest(path: Path, chunk: int = 1 << 20) -> str:
    """sha256 of a file's bytes, read in chunks: what ``done.json`` records of each artifact."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def check_done(job_dir: Path, digests: bool = True) -> str | None:
    """Why the job in ``job_dir`` is not done, or None when it is.

    Done means: done.json is there and reads as JSON, and every artifact it lists is there
    with the size (and, with ``digests``, the sha256) it had when the job finished. A
    done.json of an older icefarm, without the list, only has to read as JSON.
    """
    job_dir = Path(job_dir)
    try:
        text = (job_dir / DONE).read_text()
    except FileNotFoundError:
        return f"no {DONE}"
    except (OSError, UnicodeDecodeError) as exc:
        return f"{DONE} unreadable ({exc})"
    try:
        done = json.loads(text)
    except ValueError:
        return f"{DONE} is damaged (not JSON: truncated?)"
    if not isinstance(done, dict):
        return f"{DONE} is damaged (not a JSON object)"
    listed = done.get("artifacts")
    if listed is None:
        return None
    if not isinstance(listed, dict):
        return f"{DONE} is damaged (its artifacts are not a mapping)"
    for name, entry in listed.items():
        path = job_dir / name
        try:
            size = path.stat().st_size
        except OSError:
            return f"{name} is missing"
        if not isinstance(entry, dict) or size != entry.get("size"):
            recorded = entry.get("size") if isinstance(entry, dict) else "?"
            return f"{name} changed size ({size} bytes, {DONE} says {recorded})"
        if digests and entry.get("sha256") and file_digest(path) != entry["sha256"]:
            return f"{name} changed (its sha256 is not the one {DONE} recorded)"
    return None


# ---------------------------------------------------------------- the views
def write_views(job_dir: Path, views: Sequence[tuple[str, str, float | None]]) -> None:
    """``views.json``: per view ``(name, frame, icicle_px)``, in order, its ``index``, ``name``,
    ``frame`` (``all`` or ``ice``), ``stem`` (`view_stem`: its images' stem) and ``icicle_px``
    (how wide, in pixels, its densest icicles are; null where not measured)."""
    (Path(job_dir) / VIEWS).write_text(json.dumps([
        {"index": i, "name": name, "frame": frame, "stem": view_stem(i), "icicle_px": px}
        for i, (name, frame, px) in enumerate(views)], indent=1) + "\n")


def read_views(job_dir: Path) -> list[dict[str, Any]]:
    """The entries of the job's ``views.json`` (one per rendered view), or [] without a usable one."""
    try:
        views = json.loads((Path(job_dir) / VIEWS).read_text())
    except (OSError, ValueError):
        return []
    return [v for v in views if isinstance(v, dict)] if isinstance(views, list) else []


# ---------------------------------------------------------------- the sweep folder
def read_jobs_csv(path: Path) -> tuple[list[dict[str, Any]], tuple[str, ...]]:
    """Rows of jobs.csv (`icefarm.farm.sweep_folder.jobs_csv_text`) in job order, and its swept
    columns (those between ``object`` and ``status``); none when it is missing or has no
    ``job_id`` column."""
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            rows = [r for r in reader if r.get("job_id")]
            fields = reader.fieldnames or []
    except OSError:
        return [], ()
    if "job_id" not in fields:
        return [], ()
    swept: tuple[str, ...] = ()
    if "object" in fields and "status" in fields:
        swept = tuple(fields[fields.index("object") + 1:fields.index("status")])
    return rows, swept


# What a job writes beside `JOB_FILES`: its folders and the files named by pattern (views,
# POV-Ray's renders, sky images).
JOB_FOLDERS = (GROWTH_DIR, *LATER)
JOB_PATTERNS = (f"{RENDER_STEM}_view*.*", f"{POVRAY_STEM}*.png", "sky_*.*", ".*.tmp")


def clear_job(job_dir: Path) -> list[str]:
    """Remove from ``job_dir`` everything an earlier job wrote there (its files, ``growth/``,
    and the ``renders/`` and ``export/`` made from it), so that a new job's ``done.json``
    vouches only for the new job's files; other files are left where they are.

    Returns
    -------
    list of str
        The names removed (top level), sorted; empty for a new or an empty folder.
    """
    job_dir = Path(job_dir)
    if not job_dir.is_dir():
        return []
    removed = []
    for path in sorted(job_dir.iterdir()):
        name = path.name
        if name in JOB_FILES or name in JOB_FOLDERS or any(path.match(p) for p in JOB_PATTERNS):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
            removed.append(name)
    return removed


def is_job_dir(path: Path) -> bool:
    """``path`` holds a job's records (`RECORDS`)."""
    return any((Path(path) / name).is_file() for name in RECORDS)


@dataclass(frozen=True)
class SweepFolder:
    """A sweep folder as `scan_sweep` finds it.

    Attributes
    ----------
    path : Path
    job_dirs : tuple of Path
        Every job folder, started or not, in job order: jobs.csv's first, then the others
        by path.
    rows : tuple of dict
        jobs.csv's rows, in its order (none without it).
    swept : tuple of str
        jobs.csv's swept columns.
    """

    path: Path
    job_dirs: tuple[Path, ...]
    rows: tuple[dict[str, Any], ...] = ()
    swept: tuple[str, ...] = ()

    @property
    def is_sweep(self) -> bool:
        """A sweep folder proper (it has ``jobs/``), not a job folder or a folder above some."""
        return (self.path / JOBS_DIR).is_dir()

    def manifest(self) -> dict[str, Any]:
        """``manifest.resolved.yaml``; empty when missing, unreadable or not a mapping."""
        try:
            loaded = load_yaml((self.path / MANIFEST).read_text())
        except (OSError, yaml.YAMLError):
            return {}
        return loaded if isinstance(loaded, dict) else {}


def scan_sweep(run_dir: Path) -> SweepFolder:
    """The job folders under ``run_dir``, in the one job order every reader (the report, the
    contact sheets) uses.

    ``run_dir`` is a sweep folder (``jobs/<object>/<job>/``: every folder there, started or
    not, except hidden ones), one job folder, or any folder above job folders (those found
    by their records). Jobs that ``jobs.csv`` lists come first, in its order; the others
    follow by path.
    """
    run_dir = Path(run_dir)
    if (run_dir / JOBS_DIR).is_dir():
        found = sorted(p for p in (run_dir / JOBS_DIR).glob("*/*") if p.is_dir() and not p.name.startswith("."))
    elif is_job_dir(run_dir):
        return SweepFolder(run_dir, (run_dir,))
    else:
        found = sorted({p.parent for name in RECORDS for p in run_dir.rglob(name)})
    rows, swept = read_jobs_csv(run_dir / JOBS_CSV)
    rank: dict[tuple[str, str] | None, int] = {(r.get("object") or "", r["job_id"]): i for i, r in enumerate(rows)}
    if rank:
        found.sort(key=lambda p: (rank.get(_object_and_job(run_dir, p), len(rank)), str(p)))
    return SweepFolder(run_dir, tuple(found), tuple(rows), swept)


def _object_and_job(run_dir: Path, job_dir: Path) -> tuple[str, str] | None:
    """``(object, job id)`` of a job folder at ``jobs/<object>/<job id>`` under ``run_dir``."""
    parts = job_dir.relative_to(run_dir).parts
    return (parts[1], parts[2]) if len(parts) == 3 and parts[0] == JOBS_DIR else None
