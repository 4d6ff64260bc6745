"""Lookdev contact sheets (OpenImageIO) and an HTML gallery of one sweep folder.

Reads the artifact contract of DESIGN.md ("Artifacts")::

    RUN_DIR/jobs/<object>/<job>/  params.yaml, render.exr (linear), render.png (sRGB),
                                  timings.json, scene.xml, ice.ply, done.json | error.json,
                                  views.json and render_view<i>.exr (optional: the views)
    RUN_DIR/jobs.csv              optional: job order (``job_id`` column) and swept columns
    RUN_DIR/manifest.resolved.yaml optional: sweep name and method

and writes::

    RUN_DIR/sheets/<object>.exr   the sheet, linear Rec.709 (half), for pixel comparison
    RUN_DIR/sheets/<object>.png   the same after one display transform to sRGB, for review
    RUN_DIR/sheets/index.html     every sheet and every job, opened straight from disk

A cell shows the job's main render, or its ice view (a render zoomed on the densest
icicles, ``frame: ice`` in ``views.json``) where the main render would show the icicles
under `ICE_VIEW_BELOW_PX` pixels wide at the cell's size; such a cell is tagged "ice view".

The parameters that vary are found per object by comparing the ``params.yaml`` of its jobs,
so the sheets do not depend on the manifest's format. Two varying parameters give a grid
whose rows and columns are their values; one gives a row (wrapped when long); three or
more, a random sweep or a zip sweep give a grid in job order.

Everything is composited in linear light, and the display transform runs once, on the
whole sheet, for the PNG. Text and placeholder colours are stated as the sRGB values they
should show and converted to linear before drawing, so they come out as intended.

Layout of a sheet (pixels; ``CW``, ``CH`` the cell image size)::

    MARGIN
    HEADER_H                         five lines: sweep / object, counts and date, axes, fixed
    COL_HEAD_H                       column values (two-parameter grids only)
    rows x (CH + LABEL_H) + (rows - 1) x GAP     LABEL_H: two lines under each cell
    MARGIN
    width = max(MIN_WIDTH, 2 MARGIN + ROW_HEAD_W + cols CW + (cols - 1) GAP)

``ROW_HEAD_W`` and ``COL_HEAD_H`` are zero unless the sheet is a two-parameter grid.
"""

from __future__ import annotations

import csv
import datetime as _dt
import enum
import html
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import yaml

from . import params as P
from .artifacts import atomic_write
from .errors import InputError
from .jobdir import DONE, ERROR, PARAMS, TIMINGS, error_line, total_seconds

# Layout, in pixels.
MARGIN = 16
GAP = 8
HEADER_H = 124
LABEL_H = 40
ROW_HEAD_W = 120
COL_HEAD_H = 28
MIN_WIDTH = 640
DEFAULT_ASPECT = 0.75  # cell height / width when no render can be read
WRAP_AFTER = 8  # a one-parameter sweep longer than this wraps into a grid
ICE_VIEW_BELOW_PX = 4.0  # icicles narrower than this in a cell: show the job's ice view there
VIEWS_FILE = "views.json"  # written beside the renders (icefarm.scene.render.VIEWS_FILE)
# fit's filter: no negative lobes (no ringing around highlights, no negative linear values)
# and 4x faster than its default lanczos3 (40 ms against 170 ms for 320x240 into 160x120).
FIT_FILTER = "blackman-harris"

FONT = "DroidSans"
FONT_BOLD = "DroidSans-Bold"
TITLE_SIZE = 22
TEXT_SIZE = 14
LABEL_SIZE = 13

# Colours as the sRGB display values they should show (converted to linear before drawing).
BACKGROUND_SRGB = (0.12, 0.12, 0.13)
TEXT_SRGB = (0.92, 0.92, 0.92)
DIM_TEXT_SRGB = (0.62, 0.62, 0.64)
FAILED_SRGB = (0.50, 0.10, 0.10)
UNFINISHED_SRGB = (0.30, 0.30, 0.34)
EMPTY_SRGB = (0.18, 0.18, 0.19)

SHEETS_DIR = "sheets"


class JobState(enum.Enum):
    """What a job folder holds, as the sheet and the gallery show it."""

    DONE = "done"  # done.json (and normally render.exr)
    FAILED = "failed"  # error.json without done.json
    UNFINISHED = "unfinished"  # neither: pending, running, or killed


class Arrangement(enum.Enum):
    """How the cells of a sheet are laid out."""

    ROWS_COLUMNS = "rows x columns"  # two varying parameters
    ROW = "row"  # one varying parameter (wrapped into a grid when long)
    JOB_ORDER = "grid in job order"  # none, three or more, random or zip sweeps


@dataclass(frozen=True)
class SheetResult:
    """One object's contact sheet.

    Attributes
    ----------
    object_id : str
    png, exr : Path
        ``RUN_DIR/sheets/<object>.png`` (sRGB) and ``.exr`` (linear).
    rows, cols : int
        Grid size in cells.
    cells : int
        Jobs placed on the sheet (empty grid slots not counted).
    failed : int
        Jobs shown as failed (error.json).
    """

    object_id: str
    png: Path
    exr: Path
    rows: int
    cols: int
    cells: int
    failed: int


@dataclass(frozen=True)
class JobInfo:
    """One job of the sweep folder, as read from disk.

    Attributes
    ----------
    path : Path or None
        The job folder; None for a job listed in jobs.csv whose folder does not exist.
    values : dict
        Flat ``{"group.name": value}``: the full parameters (params.yaml), or only the
        swept values of jobs.csv when params.yaml is missing.
    has_params : bool
        ``values`` came from params.yaml.
    error : dict or None
        error.json (``stage``, ``message``, ``traceback``).
    timings : dict or None
        timings.json.
    """

    object_id: str
    job_id: str
    path: Path | None
    state: JobState
    values: dict
    has_params: bool
    error: dict | None
    timings: dict | None

    def file(self, name: str) -> Path | None:
        """``path / name`` if that file exists."""
        if self.path is None or not (self.path / name).is_file():
            return None
        return self.path / name


@dataclass(frozen=True)
class RunInfo:
    """A sweep folder: its name, method, swept keys and jobs per object (in job order)."""

    run_dir: Path
    name: str
    method: str | None
    swept: tuple[str, ...]
    objects: dict[str, list[JobInfo]]


@dataclass(frozen=True)
class Grid:
    """Where each job goes on a sheet.

    Attributes
    ----------
    slots : list
        ``(row, col, job)`` for every placed job.
    row_key, col_key : str or None
        The two parameters of a rows x columns grid.
    row_values, col_values : list
        Their values, sorted, one per row / column.
    """

    arrangement: Arrangement
    rows: int
    cols: int
    varying: tuple[str, ...]
    slots: list
    row_key: str | None = None
    col_key: str | None = None
    row_values: tuple = ()
    col_values: tuple = ()


# --------------------------------------------------------------------------- reading

def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _read_params(path: Path) -> dict | None:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return P.flatten(data) if isinstance(data, Mapping) else None


def _read_jobs_csv(path: Path) -> tuple[list[dict], tuple[str, ...]]:
    """Rows of jobs.csv and its swept columns (those between ``object`` and ``status``)."""
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            rows = [r for r in reader if r.get("job_id")]
            fields = reader.fieldnames or []
    except OSError:
        return [], ()
    if "job_id" not in fields:
        return [], ()
    swept = ()
    if "object" in fields and "status" in fields:
        swept = tuple(fields[fields.index("object") + 1:fields.index("status")])
    return rows, swept


def _job_state(path: Path) -> JobState:
    if (path / DONE).is_file():
        return JobState.DONE
    if (path / ERROR).is_file():
        return JobState.FAILED
    return JobState.UNFINISHED


def scan_run(run_dir: Path, sweep_name: str | None = None) -> RunInfo:
    """Read a sweep folder: every job of every object, in job order.

    Job order is the order of ``jobs.csv`` when it exists (jobs it does not list follow,
    sorted by their varying values); otherwise the jobs sorted by their varying values.

    Raises
    ------
    InputError
        ``run_dir`` has no ``jobs/`` folder.
    """
    run_dir = Path(run_dir)
    jobs_root = run_dir / "jobs"
    if not jobs_root.is_dir():
        raise InputError(f"{run_dir} is not a sweep folder: it has no jobs/ folder "
                         f"(give the folder `icefarm sweep` wrote, <out>/<sweep name>)")
    manifest = {}
    if (run_dir / "manifest.resolved.yaml").is_file():
        try:
            loaded = yaml.safe_load((run_dir / "manifest.resolved.yaml").read_text())
            manifest = loaded if isinstance(loaded, Mapping) else {}
        except (OSError, yaml.YAMLError):
            manifest = {}
    name = sweep_name or str(manifest.get("name") or run_dir.name)
    sweep = manifest.get("sweep") if isinstance(manifest.get("sweep"), Mapping) else {}
    method = sweep.get("method") if isinstance(sweep.get("method"), str) else None
    csv_rows, swept = _read_jobs_csv(run_dir / "jobs.csv")

    objects: dict[str, dict[str, JobInfo]] = {}
    for obj_dir in sorted(p for p in jobs_root.iterdir() if p.is_dir()):
        for job_dir in sorted(p for p in obj_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
            values = _read_params(job_dir / PARAMS)
            objects.setdefault(obj_dir.name, {})[job_dir.name] = JobInfo(
                object_id=obj_dir.name, job_id=job_dir.name, path=job_dir, state=_job_state(job_dir),
                values=values or {}, has_params=values is not None,
                error=_read_json(job_dir / ERROR), timings=_read_json(job_dir / TIMINGS))
    csv_order: dict[str, list[str]] = {}
    for row in csv_rows:
        obj, job = row.get("object") or "", row["job_id"]
        csv_order.setdefault(obj, []).append(job)
        known = objects.setdefault(obj, {})
        if job in known:
            if not known[job].has_params:  # fall back on the swept values jobs.csv lists
                known[job] = _with_values(known[job], _csv_values(row, swept))
        elif obj:
            known[job] = JobInfo(object_id=obj, job_id=job, path=None, state=JobState.UNFINISHED,
                                 values=_csv_values(row, swept), has_params=False, error=None, timings=None)

    ordered: dict[str, list[JobInfo]] = {}
    for obj, jobs in objects.items():
        if not jobs:
            continue
        vary = varying_keys(list(jobs.values()), swept)
        first = [jobs[j] for j in dict.fromkeys(csv_order.get(obj, [])) if j in jobs]
        listed = {j.job_id for j in first}
        rest = sorted((j for j in jobs.values() if j.job_id not in listed),
                      key=lambda j: (tuple(_sort_key(j.values.get(k)) for k in vary), j.job_id))
        ordered[obj] = first + rest
    return RunInfo(run_dir=run_dir, name=name, method=method, swept=swept, objects=ordered)


def _with_values(job: JobInfo, values: dict) -> JobInfo:
    return JobInfo(job.object_id, job.job_id, job.path, job.state, values, False, job.error, job.timings)


def _csv_values(row: Mapping[str, str], swept: Sequence[str]) -> dict:
    out = {}
    for key in swept:
        raw = row.get(key, "")
        if raw:
            value = P.parse_value(raw)
            # jobs.csv writes vectors as "0 -1 0"
            if isinstance(value, str) and all(_is_number(t) for t in value.split()):
                value = [float(t) for t in value.split()]
            out[key] = value
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------- parameters

def _canon(value: Any) -> str:
    """A comparable form of a parameter value (1 == 1.0; lists by their items)."""
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, (int, float)):
        return repr(float(value))
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_canon(v) for v in value) + "]"
    return repr(value)


def _sort_key(value: Any) -> tuple:
    if value is None:
        return (3, "")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return (0, float(value))
    if isinstance(value, (list, tuple)):
        return (2, tuple(_sort_key(v) for v in value))
    return (1, str(value))


def varying_keys(jobs: Sequence[JobInfo], order: Sequence[str] = ()) -> list[str]:
    """Parameters whose value differs between the jobs, in ``order`` then Table 1 order.

    A key missing from some jobs (an older params.yaml) counts as varying only if the jobs
    that have it disagree.
    """
    seen: dict[str, set] = {}
    for job in jobs:
        for key, value in job.values.items():
            seen.setdefault(key, set()).add(_canon(value))
    keys = [k for k, v in seen.items() if len(v) > 1]
    rank = {k: i for i, k in enumerate(order)}
    table = {k: i for i, k in enumerate(P.param_index())}
    return sorted(keys, key=lambda k: (rank.get(k, len(rank)), table.get(k, len(table)), k))


def fixed_changes(jobs: Sequence[JobInfo], varying: Sequence[str]) -> dict[str, Any]:
    """Parameters shared by all the jobs that differ from `icefarm.params.defaults`."""
    defaults = P.flatten(P.defaults())
    with_params = [j for j in jobs if j.has_params]
    if not with_params:
        return {}
    out = {}
    for key, value in with_params[0].values.items():
        if key in varying or any(_canon(j.values.get(key)) != _canon(value) for j in with_params[1:]):
            continue
        if key not in defaults or _canon(defaults[key]) != _canon(value):
            out[key] = value
    return out


def _unique_names() -> set[str]:
    names = [p.name for p in P.PARAMS]
    return {n for n in names if names.count(n) == 1}


def short_name(key: str) -> str:
    """``trajectories.curve_angle`` -> ``curve_angle`` where the name alone is unambiguous."""
    group, _, name = key.rpartition(".")
    return name if group and name in _unique_names() else key


def format_value(key: str, value: Any) -> str:
    """A value with its unit: ``2 deg``, ``0.004 m``, ``tubes``, ``0 -1 0``."""
    if isinstance(value, (list, tuple)):
        text = " ".join(format_value("", v) for v in value)
    elif isinstance(value, float):
        text = f"{value:.6g}"
    else:
        text = str(value)
    param = P.param_index().get(key)
    if param is not None and param.unit not in ("-", "") and not isinstance(value, (list, tuple, str)):
        text += f" {param.unit}"
    return text


def _assignment(key: str, value: Any) -> str:
    return f"{short_name(key)}={format_value(key, value)}"


def _compact(key: str, value: Any) -> str:
    """``c=2``: the paper's symbol where it names one parameter, no unit (the header has them)."""
    param = P.param_index().get(key)
    symbols = [p.symbol for p in P.PARAMS]
    name = param.symbol if param is not None and param.symbol != "-" and symbols.count(param.symbol) == 1 \
        else short_name(key)
    return f"{name}={format_value('', value)}"


def _axis_title(key: str) -> str:
    param = P.param_index().get(key)
    if param is None:
        return key
    bits = [b for b in (param.symbol if param.symbol != "-" else "", param.unit if param.unit != "-" else "") if b]
    return f"{key} ({', '.join(bits)})" if bits else key


# --------------------------------------------------------------------------- grid

def plan_grid(jobs: Sequence[JobInfo], varying: Sequence[str], method: str | None = None) -> Grid:
    """Place the jobs of one object (in job order) on a grid.

    Two varying parameters whose values form a (nearly) full cross product give rows and
    columns; one gives a row, wrapped into a near-square grid past `WRAP_AFTER` cells;
    anything else, and every random sweep, a near-square grid in job order.
    """
    n = len(jobs)
    if n == 0:
        raise ValueError("plan_grid needs at least one job")
    varying = tuple(varying)
    if len(varying) == 2 and method != "random":
        row_key, col_key = varying
        missing = object()
        pairs = [(_canon(j.values.get(row_key, missing)), _canon(j.values.get(col_key, missing))) for j in jobs]
        row_values = _distinct(jobs, row_key)
        col_values = _distinct(jobs, col_key)
        complete = all(row_key in j.values and col_key in j.values for j in jobs)
        if complete and len(set(pairs)) == n and len(row_values) * len(col_values) <= 2 * n:
            rindex = {_canon(v): i for i, v in enumerate(row_values)}
            cindex = {_canon(v): i for i, v in enumerate(col_values)}
            slots = [(rindex[_canon(j.values[row_key])], cindex[_canon(j.values[col_key])], j) for j in jobs]
            return Grid(Arrangement.ROWS_COLUMNS, len(row_values), len(col_values), varying, slots,
                        row_key, col_key, tuple(row_values), tuple(col_values))
    if len(varying) == 1 and method != "random":
        arrangement = Arrangement.ROW
        cols = n if n <= WRAP_AFTER else math.ceil(math.sqrt(n))
    else:
        arrangement = Arrangement.JOB_ORDER
        cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    slots = [(i // cols, i % cols, j) for i, j in enumerate(jobs)]
    return Grid(arrangement, rows, cols, varying, slots)


def _distinct(jobs: Sequence[JobInfo], key: str) -> list:
    values = {}
    for j in jobs:
        if key in j.values:
            values.setdefault(_canon(j.values[key]), j.values[key])
    return sorted(values.values(), key=_sort_key)


def sheet_size(grid: Grid, cell_width: int, cell_height: int) -> tuple[int, int]:
    """``(width, height)`` of a sheet in pixels (see the module docstring)."""
    row_head, col_head = _heads(grid)
    width = 2 * MARGIN + row_head + grid.cols * cell_width + (grid.cols - 1) * GAP
    height = 2 * MARGIN + HEADER_H + col_head + grid.rows * (cell_height + LABEL_H) + (grid.rows - 1) * GAP
    return max(MIN_WIDTH, width), height


def cell_origin(grid: Grid, row: int, col: int, cell_width: int, cell_height: int) -> tuple[int, int]:
    """Top-left pixel ``(x, y)`` of a cell's image."""
    row_head, col_head = _heads(grid)
    return (MARGIN + row_head + col * (cell_width + GAP),
            MARGIN + HEADER_H + col_head + row * (cell_height + LABEL_H + GAP))


def _heads(grid: Grid) -> tuple[int, int]:
    if grid.arrangement is Arrangement.ROWS_COLUMNS:
        return ROW_HEAD_W, COL_HEAD_H
    return 0, 0


# --------------------------------------------------------------------------- drawing

def srgb_to_linear(srgb: Sequence[float]) -> tuple[float, ...]:
    """The linear Rec.709 value that the sRGB display transform turns into ``srgb``."""
    v = np.asarray(srgb, dtype=np.float64)
    lin = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    return tuple(float(x) for x in lin)


def _oiio():
    import OpenImageIO as oiio  # imported late: `icefarm --help` need not load it

    return oiio


def _text(buf, x: int, y: int, text: str, size: int, srgb, font: str = FONT, align: str = "left") -> None:
    """Draw one line; ``y`` is the top of the line box (the baseline is placed below it)."""
    oiio = _oiio()
    if not text:
        return
    ok = oiio.ImageBufAlgo.render_text(buf, int(x), int(y + round(size * 0.95)), text, size, font,
                                       srgb_to_linear(srgb), alignx=align)
    if not ok:
        raise RuntimeError(f"OpenImageIO render_text failed: {buf.geterror()}")


def _width(text: str, size: int, font: str = FONT) -> int:
    if not text:
        return 0
    return _oiio().ImageBufAlgo.text_size(text, size, font).width


def _clip(text: str, width: int, size: int, font: str = FONT) -> str:
    """``text`` cut (ending in ...) to fit ``width`` pixels."""
    if _width(text, size, font) <= width:
        return text
    lo, hi = 0, len(text)
    while lo < hi:  # longest prefix that fits with the ellipsis
        mid = (lo + hi + 1) // 2
        if _width(text[:mid].rstrip() + "...", size, font) <= width:
            lo = mid
        else:
            hi = mid - 1
    return text[:lo].rstrip() + "..." if lo else ""


def _wrap(parts: Sequence[str], width: int, size: int, max_lines: int, sep: str = "  ",
          font: str = FONT) -> list[str]:
    """Greedy wrap of ``parts`` into at most ``max_lines`` lines of ``width`` pixels."""
    lines: list[str] = []
    current = ""
    for i, part in enumerate(parts):
        candidate = f"{current}{sep}{part}" if current else part
        if _width(candidate, size, font) <= width or not current:
            current = candidate
            continue
        lines.append(current)
        current = part
        if len(lines) == max_lines:
            break
    else:
        lines.append(current)
        return [_clip(line, width, size, font) for line in lines]
    # ran out of lines: say how much was left out
    suffix = f"{sep}(+{len(parts) - i} more)"
    lines[-1] = _clip(lines[-1], width - _width(suffix, size, font), size, font) + suffix
    return [_clip(line, width, size, font) for line in lines]


def _fill(buf, x: int, y: int, w: int, h: int, srgb) -> None:
    oiio = _oiio()
    oiio.ImageBufAlgo.fill(buf, srgb_to_linear(srgb), roi=oiio.ROI(x, x + w, y, y + h, 0, 1, 0, 3))


def _fitted(path: Path, width: int, height: int):
    """The render at ``path`` fitted into ``width x height`` without distortion (letterboxed
    in black), as an RGB buffer whose data window is exactly that frame."""
    oiio = _oiio()
    src = oiio.ImageBuf(str(path))
    if src.has_error or src.spec().width <= 0:
        raise OSError(src.geterror() or f"cannot read {path}")
    if src.nchannels != 3:  # drop alpha (renders are premultiplied), widen grey
        src = oiio.ImageBufAlgo.channels(src, (0, 1, 2) if src.nchannels >= 3 else (0, 0, 0))
    fitted = oiio.ImageBufAlgo.fit(src, filtername=FIT_FILTER, fillmode="letterbox",
                                   roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3))
    if fitted.has_error:
        raise OSError(fitted.geterror())
    # fit leaves the data window on the picture; crop pads it back to the frame with zeros.
    return oiio.ImageBufAlgo.crop(fitted, oiio.ROI(0, width, 0, height, 0, 1, 0, 3))


def _cell_aspect(jobs: Sequence[JobInfo]) -> float:
    oiio = _oiio()
    for job in jobs:
        exr = job.file("render.exr")
        if exr is None:
            continue
        image = oiio.ImageInput.open(str(exr))  # the header only
        if image is None:
            continue
        s = image.spec()
        image.close()
        if s.width > 0 and s.height > 0:
            return s.height / s.width
    return DEFAULT_ASPECT


def _image_width(path: Path) -> int | None:
    """Width in pixels of an image, from its header."""
    image = _oiio().ImageInput.open(str(path))
    if image is None:
        return None
    width = image.spec().width
    image.close()
    return width if width > 0 else None


def _views(job: JobInfo) -> list[dict]:
    """The job's ``views.json`` (one entry per rendered view), or [] without a usable one."""
    path = job.file(VIEWS_FILE)
    if path is None:
        return []
    try:
        views = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [v for v in views if isinstance(v, Mapping)] if isinstance(views, list) else []


def cell_render(job: JobInfo, cell_width: int) -> tuple[Path | None, str | None]:
    """The EXR a cell of ``cell_width`` pixels shows, and the name of its view if not the main one.

    The main render, unless its densest icicles (``icicle_px`` of view 0 in
    ``views.json``) would be under `ICE_VIEW_BELOW_PX` pixels wide at the cell's size and
    the job has an ice view (``frame: ice``) rendered: then that view.
    """
    exr = job.file("render.exr")
    views = _views(job)
    if exr is None or not views:
        return exr, None
    px = views[0].get("icicle_px")
    if isinstance(px, bool) or not isinstance(px, (int, float)) or not math.isfinite(px):
        return exr, None
    width = _image_width(exr)
    if width is None or px * cell_width / width >= ICE_VIEW_BELOW_PX:
        return exr, None
    for view in views[1:]:
        stem = view.get("stem")
        if view.get("frame") == "ice" and isinstance(stem, str) and "/" not in stem:
            zoomed = job.file(f"{stem}.exr")
            if zoomed is not None:
                return zoomed, str(view.get("name") or "ice")
    return exr, None


def _seconds(job: JobInfo) -> float | None:
    data = job.timings if job.timings is not None else (job.error or {})
    return total_seconds(data.get("seconds"))


def _placeholder(buf, x: int, y: int, w: int, h: int, srgb, title: str, lines: Sequence[str]) -> None:
    _fill(buf, x, y, w, h, srgb)
    pad = 8
    top = y + max(pad, h // 2 - 20 - 8 * len(lines))
    _text(buf, x + w // 2, top, _clip(title, w - 2 * pad, 18, FONT_BOLD), 18, TEXT_SRGB, FONT_BOLD, "center")
    top += 26
    for line in lines:
        if top + 16 > y + h:
            break
        _text(buf, x + w // 2, top, line, 12, TEXT_SRGB, align="center")
        top += 16


def _draw_cell(buf, job: JobInfo, x: int, y: int, cw: int, ch: int, label_keys: Sequence[str]) -> str:
    """Draw one job into the cell at ``(x, y)``; returns what was drawn (``render``, a state)."""
    oiio = _oiio()
    inner = cw - 16
    exr, view = cell_render(job, cw)
    drawn = "render"
    if job.state is JobState.FAILED:
        err = job.error or {}
        message = error_line(err.get("message"), "no error.json message")
        _placeholder(buf, x, y, cw, ch, FAILED_SRGB, "FAILED",
                     [_clip(f"stage: {err.get('stage', '?')}", inner, 12)]
                     + _wrap(message.split(), inner, 12, 3, sep=" "))
        drawn = "failed"
    elif exr is None:
        reason = ("done, but no render (no render config, or --until)" if job.state is JobState.DONE
                  else "unfinished: no done.json" if job.path is not None else "not run: no job folder")
        _placeholder(buf, x, y, cw, ch, UNFINISHED_SRGB, "NOT RENDERED", _wrap(reason.split(), inner, 12, 2, sep=" "))
        drawn = "not rendered"
    else:
        try:
            cell = _fitted(exr, cw, ch)
            if not oiio.ImageBufAlgo.paste(buf, x, y, 0, 0, cell):
                raise OSError(buf.geterror())
            if view is not None:  # say that this cell is zoomed on the ice
                tag = _clip(f"{view} view", cw - 8, 12)
                _fill(buf, x, y, _width(tag, 12) + 8, 18, BACKGROUND_SRGB)
                _text(buf, x + 4, y + 2, tag, 12, TEXT_SRGB)
        except OSError as exc:
            _placeholder(buf, x, y, cw, ch, FAILED_SRGB, "UNREADABLE RENDER",
                         _wrap(str(exc).split(), inner, 12, 3, sep=" "))
            drawn = "unreadable"

    # label strip: the varying values; then the job id, time or state
    keys = [k for k in label_keys if k in job.values]
    parts = [_assignment(k, job.values[k]) for k in keys] or [f"job {job.job_id}"]
    lines = _wrap(parts, cw - 4, LABEL_SIZE, 2)
    if keys and any(line.endswith(("...", "more)")) for line in lines):  # too long: paper symbols
        lines = _wrap([_compact(k, job.values[k]) for k in keys], cw - 4, LABEL_SIZE, 2)
    values_lines = len(lines)
    if len(lines) < 2:
        seconds = _seconds(job)
        status = {"render": "", "failed": f"failed at {(job.error or {}).get('stage', '?')}",
                  "not rendered": "not rendered", "unreadable": "render unreadable"}[drawn]
        if drawn == "render" and job.state is JobState.UNFINISHED:
            status = "unfinished"
        bits = [f"job {job.job_id}", f"{seconds:.1f} s" if seconds is not None else "", status]
        lines.append(_clip(" · ".join(b for b in bits if b), cw - 4, LABEL_SIZE))
    for i, line in enumerate(lines):
        _text(buf, x + 2, y + ch + 4 + i * 17, line, LABEL_SIZE, TEXT_SRGB if i < values_lines else DIM_TEXT_SRGB)
    return drawn


def _draw_header(buf, width: int, run: RunInfo, object_id: str, jobs: Sequence[JobInfo], grid: Grid,
                 counts: Mapping[str, int], date: str) -> None:
    inner = width - 2 * MARGIN
    x, y = MARGIN, MARGIN
    _text(buf, x, y, _clip(f"{run.name}  ·  {object_id}", inner, TITLE_SIZE, FONT_BOLD), TITLE_SIZE,
          TEXT_SRGB, FONT_BOLD)
    y += 32
    state = [f"{len(jobs)} job{'s' if len(jobs) != 1 else ''}"]
    state += [f"{counts[k]} {k}" for k in ("failed", "not rendered", "unreadable") if counts.get(k)]
    method = f"{run.method} sweep" if run.method else "sweep"
    _text(buf, x, y, _clip(f"{method}: {', '.join(state)}   ·   {date}", inner, TEXT_SIZE), TEXT_SIZE, DIM_TEXT_SRGB)
    y += 20
    if grid.arrangement is Arrangement.ROWS_COLUMNS:
        axes = f"rows: {_axis_title(grid.row_key)}   ×   columns: {_axis_title(grid.col_key)}"
    elif grid.arrangement is Arrangement.ROW:
        axes = f"varying: {_axis_title(grid.varying[0])}"
    elif grid.varying:
        axes = "grid in job order, varying: " + ", ".join(_axis_title(k) for k in grid.varying)
    else:
        axes = "no parameter varies between these jobs"
    _text(buf, x, y, _clip(axes, inner, TEXT_SIZE), TEXT_SIZE, TEXT_SRGB)
    y += 20
    fixed = fixed_changes(jobs, grid.varying)
    if fixed:
        parts = [_assignment(k, v) for k, v in fixed.items()]
        parts[0] = "fixed (not default): " + parts[0]
        lines = _wrap(parts, inner, TEXT_SIZE, 2)
    else:
        lines = ["fixed: every other parameter at its default"]
    for line in lines:
        _text(buf, x, y, line, TEXT_SIZE, DIM_TEXT_SRGB)
        y += 20


def _draw_heads(buf, grid: Grid, cw: int, ch: int) -> None:
    for c, value in enumerate(grid.col_values):
        x, y = cell_origin(grid, 0, c, cw, ch)
        text = _clip(_assignment(grid.col_key, value), cw, TEXT_SIZE, FONT_BOLD)
        _text(buf, x + cw // 2, y - COL_HEAD_H + 4, text, TEXT_SIZE, TEXT_SRGB, FONT_BOLD, "center")
    for r, value in enumerate(grid.row_values):
        x, y = cell_origin(grid, r, 0, cw, ch)
        left, width = MARGIN, ROW_HEAD_W - GAP
        _text(buf, left, y + ch // 2 - 20, _clip(short_name(grid.row_key), width, TEXT_SIZE), TEXT_SIZE,
              DIM_TEXT_SRGB)
        _text(buf, left, y + ch // 2, _clip(format_value(grid.row_key, value), width, TEXT_SIZE + 2, FONT_BOLD),
              TEXT_SIZE + 2, TEXT_SRGB, FONT_BOLD)


def _write_image(buf, path: Path, fmt: str, dtype: str) -> None:
    """Write through a temporary file and a rename, so a reader never sees half a sheet."""
    oiio = _oiio()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    buf.set_write_format(dtype)
    if fmt == "openexr":
        buf.specmod().attribute("compression", "zip")
    if not buf.write(str(tmp), fileformat=fmt):
        tmp.unlink(missing_ok=True)
        raise OSError(f"cannot write {path}: {buf.geterror() or oiio.geterror()}")
    os.replace(tmp, path)


def build_sheet(run: RunInfo, object_id: str, cell_width: int = 320, date: str | None = None) -> SheetResult:
    """Compose, write and describe one object's sheet (see `build_sheets`)."""
    oiio = _oiio()
    jobs = run.objects[object_id]
    grid = plan_grid(jobs, varying_keys(jobs, run.swept), run.method)
    cw = int(cell_width)
    ch = max(1, round(cw * _cell_aspect(jobs)))
    width, height = sheet_size(grid, cw, ch)
    buf = oiio.ImageBuf(oiio.ImageSpec(width, height, 3, "half"))
    _fill(buf, 0, 0, width, height, BACKGROUND_SRGB)

    counts: dict[str, int] = {}
    occupied = set()
    for r, c, job in grid.slots:
        x, y = cell_origin(grid, r, c, cw, ch)
        drawn = _draw_cell(buf, job, x, y, cw, ch, grid.varying)
        counts[drawn] = counts.get(drawn, 0) + 1
        occupied.add((r, c))
    if grid.arrangement is Arrangement.ROWS_COLUMNS:
        _draw_heads(buf, grid, cw, ch)
        for r in range(grid.rows):  # a cross product with holes: say so in the hole
            for c in range(grid.cols):
                if (r, c) not in occupied:
                    x, y = cell_origin(grid, r, c, cw, ch)
                    _placeholder(buf, x, y, cw, ch, EMPTY_SRGB, "no job", ["not in this sweep"])
    _draw_header(buf, width, run, object_id, jobs, grid, counts,
                 date or _dt.datetime.now().strftime("%Y-%m-%d %H:%M"))

    out = run.run_dir / SHEETS_DIR
    out.mkdir(parents=True, exist_ok=True)
    exr, png = out / f"{object_id}.exr", out / f"{object_id}.png"
    _write_image(buf, exr, "openexr", "half")
    # the one display transform of the whole sheet
    display = oiio.ImageBufAlgo.colorconvert(buf, "lin_rec709", "sRGB")
    if display.has_error:
        raise RuntimeError(f"OpenImageIO colorconvert failed: {display.geterror()}")
    _write_image(display, png, "png", "uint8")
    return SheetResult(object_id=object_id, png=png, exr=exr, rows=grid.rows, cols=grid.cols,
                       cells=len(grid.slots), failed=counts.get("failed", 0))


def build_sheets(run_dir: Path, cell_width: int = 320, sweep_name: str | None = None) -> list[SheetResult]:
    """Write a contact sheet per object of a sweep folder, and the gallery page.

    Parameters
    ----------
    run_dir : Path
        ``<out>/<sweep name>/`` as `icefarm sweep` writes it (needs ``jobs/``).
    cell_width : int
        Width of each cell's image in pixels; its height follows the renders' aspect.
    sweep_name : str, optional
        The title; by default the manifest's name, or the folder's name.

    Returns
    -------
    list of SheetResult
        One per object, in object order. Files: ``RUN_DIR/sheets/<object>.png`` (sRGB),
        ``<object>.exr`` (linear, half) and ``RUN_DIR/sheets/index.html``.

    Raises
    ------
    InputError
        ``run_dir`` is not a sweep folder, or ``cell_width`` is not a positive size.
    """
    if isinstance(cell_width, bool) or not isinstance(cell_width, int) or not 16 <= cell_width <= 4096:
        raise InputError(f"cell width must be a whole number of pixels in [16, 4096], got {cell_width!r}")
    run = scan_run(Path(run_dir), sweep_name)
    date = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    sheets = [build_sheet(run, obj, cell_width, date) for obj in run.objects]
    _write_gallery(run, sheets)
    return sheets


# --------------------------------------------------------------------------- gallery

_CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:0 2em 3em;background:#1e1e21;color:#e8e8e8}
a{color:#8cc4ff} h1{margin:.6em 0 .1em} h2{margin-top:1.6em;border-bottom:1px solid #444}
.muted{color:#9a9aa0} code{font-size:12px}
.sheet img{max-width:100%;height:auto;border:1px solid #444;display:block}
.jobs{display:grid;grid-template-columns:repeat(auto-fill,minmax(300px,1fr));gap:14px}
.job{background:#2a2a2e;border:1px solid #3a3a40;border-radius:6px;padding:8px}
.job.failed{border-color:#a33;background:#3a2424} .job.unfinished{border-color:#777;opacity:.85}
.job img{width:100%;height:auto;display:block;background:#000}
.ph{aspect-ratio:4/3;display:flex;align-items:center;justify-content:center;text-align:center;
    background:#444;color:#eee;font-weight:bold;padding:4px}
.failed .ph{background:#7f1a1a}
dl.vary{display:grid;grid-template-columns:auto 1fr;gap:0 .8em;margin:.5em 0;font-size:15px}
dl.vary dt{color:#9a9aa0} dl.vary dd{margin:0;font-weight:bold}
table{border-collapse:collapse;font-size:12px} td,th{padding:1px 6px;text-align:left}
th{color:#9a9aa0;font-weight:normal} tr.changed td{color:#ffd479}
.error{color:#ff9d9d} pre{white-space:pre-wrap;font-size:11px;max-height:20em;overflow:auto}
details{margin:.3em 0} summary{cursor:pointer;color:#9a9aa0}
"""

# Counts images that did not load, once the page has loaded (read by tests and by people).
_SCRIPT = """
window.addEventListener('load', function () {
  var bad = [];
  Array.prototype.forEach.call(document.images, function (img) {
    if (!(img.complete && img.naturalWidth > 0)) { bad.push(img.getAttribute('src')); }
  });
  document.body.dataset.images = String(document.images.length);
  document.body.dataset.missingImages = String(bad.length);
  document.body.dataset.missingList = bad.join(' ');
  var note = document.getElementById('missing');
  if (note && bad.length) { note.textContent = bad.length + ' image(s) missing: ' + bad.join(', '); }
});
"""


def _href(path: Path, start: Path) -> str:
    return quote(os.path.relpath(path, start).replace(os.sep, "/"))


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _timings_html(job: JobInfo) -> str:
    data = job.timings if job.timings is not None else ({"seconds": job.error.get("seconds")} if job.error else None)
    if not data:
        return '<p class="muted">no timings</p>'
    rows = []
    seconds = data.get("seconds")
    if isinstance(seconds, Mapping):
        for stage, s in seconds.items():
            if isinstance(s, (int, float)):
                rows.append(f"<tr><th>{_e(stage)}</th><td>{s:.3f} s</td></tr>")
        total = _seconds(job)
        if total is not None:
            rows.append(f"<tr><th><b>total</b></th><td><b>{total:.2f} s</b></td></tr>")
    for key, value in data.items():
        if key == "seconds" or isinstance(value, (Mapping, list)) and key != "reused":
            continue
        if key == "reused":
            value = ", ".join(map(str, value)) or "none"
        rows.append(f"<tr><th>{_e(key)}</th><td>{_e(value)}</td></tr>")
    return f"<table class=\"timings\">{''.join(rows)}</table>"


def _params_html(job: JobInfo, varying: Sequence[str]) -> str:
    defaults = P.flatten(P.defaults())
    index = P.param_index()
    rows = []
    for key, value in job.values.items():
        changed = key not in defaults or _canon(defaults[key]) != _canon(value)
        cls = ' class="changed"' if changed or key in varying else ""
        unit = index[key].unit if key in index and index[key].unit != "-" else ""
        rows.append(f"<tr{cls}><th>{_e(key)}</th><td>{_e(format_value('', value))}</td><td>{_e(unit)}</td></tr>")
    source = "params.yaml" if job.has_params else "jobs.csv (no params.yaml)"
    return (f"<details><summary>all parameters ({_e(source)}; changed from default highlighted)</summary>"
            f"<table>{''.join(rows)}</table></details>")


def _job_html(job: JobInfo, varying: Sequence[str], here: Path) -> str:
    state = job.state.value
    png = job.file("render.png")
    if png is not None:
        picture = (f'<a href="{_href(png, here)}"><img src="{_href(png, here)}" '
                   f'alt="render of {_e(job.job_id)}"></a>')
    elif job.state is JobState.FAILED:
        picture = f'<div class="ph">FAILED<br>stage: {_e((job.error or {}).get("stage", "?"))}</div>'
    else:
        picture = f'<div class="ph">NOT RENDERED<br>{_e(state)}</div>'
    vary = "".join(f"<dt>{_e(short_name(k))}</dt><dd>{_e(format_value(k, job.values[k]))}</dd>"
                   for k in varying if k in job.values)
    vary = f'<dl class="vary">{vary}</dl>' if vary else ""
    seconds = _seconds(job)
    meta = f'job <code>{_e(job.job_id)}</code> · {_e(state)}'
    if seconds is not None:
        meta += f" · <b>{seconds:.2f} s</b>"
    stages = (job.timings or job.error or {}).get("seconds")
    if isinstance(stages, Mapping) and stages:
        meta += "<br>" + " · ".join(f"{_e(k)} {v:.2f} s" for k, v in stages.items() if isinstance(v, (int, float)))
    error = ""
    if job.state is JobState.FAILED:
        err = job.error or {}
        error = (f'<p class="error">failed at stage <b>{_e(err.get("stage", "?"))}</b>: '
                 f'{_e(err.get("message", "no message"))}</p>')
        if err.get("traceback"):
            error += f"<details><summary>traceback</summary><pre>{_e(err['traceback'])}</pre></details>"
    links = []
    for name in ("scene.xml", "ice.ply", "render.exr", "render.png", "scene.pov", "params.yaml",
                 "timings.json", "error.json"):
        path = job.file(name)
        if path is not None:
            links.append(f'<a href="{_href(path, here)}">{_e(name)}</a>')
        elif name in ("scene.xml", "ice.ply"):
            links.append(f'<span class="muted">{_e(name)} (none)</span>')
    for view in _views(job)[1:]:
        stem = view.get("stem")
        path = job.file(f"{stem}.png") if isinstance(stem, str) and "/" not in stem else None
        if path is not None:
            links.append(f'<a href="{_href(path, here)}">{_e(view.get("name") or stem)} view</a>')
    if job.path is not None:
        links.append(f'<a href="{_href(job.path, here)}/">folder</a>')
    return (f'<article class="job {_e(state)}" id="{_e(job.object_id)}-{_e(job.job_id)}">{picture}{vary}'
            f'<p class="muted">{meta}</p>{error}<p class="links">{" · ".join(links)}</p>'
            f"<details><summary>timings and counts</summary>{_timings_html(job)}</details>"
            f"{_params_html(job, varying)}</article>")


def _gallery_html(run: RunInfo, sheets: Sequence[SheetResult]) -> str:
    here = run.run_dir / SHEETS_DIR
    by_object = {s.object_id: s for s in sheets}
    total = sum(len(j) for j in run.objects.values())
    failed = sum(j.state is JobState.FAILED for jobs in run.objects.values() for j in jobs)
    unfinished = sum(j.state is JobState.UNFINISHED for jobs in run.objects.values() for j in jobs)
    extra = [f'<a href="{_href(run.run_dir / n, here)}">{n}</a>'
             for n in ("manifest.resolved.yaml", "jobs.csv", "report.md", "report.csv") if (run.run_dir / n).is_file()]
    nav = " · ".join(f'<a href="#{_e(o)}">{_e(o)}</a>' for o in run.objects)
    body = [f"<h1>{_e(run.name)}</h1>",
            f'<p class="muted">{_e(run.method + " sweep" if run.method else "sweep")} · {len(run.objects)} '
            f"object(s) · {total} jobs · {failed} failed · {unfinished} unfinished · "
            f"built {_e(_dt.datetime.now().strftime('%Y-%m-%d %H:%M'))}"
            + (f" · {' · '.join(extra)}" if extra else "") + "</p>",
            f'<p class="error" id="missing"></p><p>objects: {nav}</p>']
    for obj, jobs in run.objects.items():
        varying = varying_keys(jobs, run.swept)
        body.append(f'<section id="{_e(obj)}"><h2>{_e(obj)}</h2>')
        sheet = by_object.get(obj)
        if sheet is not None:
            body.append(f'<figure class="sheet"><a href="{_href(sheet.png, here)}"><img src="{_href(sheet.png, here)}" '
                        f'alt="contact sheet of {_e(obj)}"></a><figcaption class="muted">{sheet.rows} × {sheet.cols} '
                        f'sheet, {sheet.cells} jobs, {sheet.failed} failed · <a href="{_href(sheet.exr, here)}">'
                        f"linear EXR</a></figcaption></figure>")
        if varying:
            body.append('<p class="muted">varying: ' + ", ".join(_e(_axis_title(k)) for k in varying) + "</p>")
        fixed = fixed_changes(jobs, varying)
        if fixed:
            body.append('<p class="muted">fixed, not default: '
                        + ", ".join(_e(_assignment(k, v)) for k, v in fixed.items()) + "</p>")
        body.append('<div class="jobs">' + "".join(_job_html(j, varying, here) for j in jobs) + "</div></section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(run.name)} · icefarm sheets</title><style>{_CSS}</style>"
            f"<script>{_SCRIPT}</script></head>\n<body>\n" + "\n".join(body) + "\n</body></html>\n")


def _write_gallery(run: RunInfo, sheets: Sequence[SheetResult]) -> Path:
    path = run.run_dir / SHEETS_DIR / "index.html"
    atomic_write(path, _gallery_html(run, sheets))
    return path


def write_gallery(run_dir: Path, sheets: list[SheetResult]) -> Path:
    """Write ``RUN_DIR/sheets/index.html``: every sheet, then every job of every object.

    Each job shows its render.png, its varying parameters (all of them in a collapsible
    table), timings, links to scene.xml and ice.ply, and for a failed job the stage and
    message. Links are relative, nothing is fetched from elsewhere, so the page works from
    disk. On load a small inline script sets ``data-missing-images`` on ``<body>`` to the
    count of images that failed to load.

    Returns
    -------
    Path
        The page.
    """
    run = scan_run(Path(run_dir))
    return _write_gallery(run, sheets)
