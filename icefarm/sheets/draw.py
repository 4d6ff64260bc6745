"""Drawing a sheet with OpenImageIO: text, cells, headers, and the sheet images themselves."""

from __future__ import annotations

import datetime as _dt
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..jobdir import DONE, ERROR, RENDER_EXR, error_line
from ..scene.images import image_size
from .gallery import write_run_gallery
from .labels import assignment, axis_title, compact_assignment, fixed_changes, format_value, short_name, varying_keys
from .layout import cell_origin, plan_grid, sheet_size
from .model import (
    BACKGROUND_SRGB,
    COL_HEAD_H,
    DEFAULT_ASPECT,
    DIM_TEXT_SRGB,
    EMPTY_SRGB,
    FAILED_SRGB,
    FIT_FILTER,
    FONT,
    FONT_BOLD,
    GAP,
    ICE_VIEW_BELOW_PX,
    LABEL_SIZE,
    MARGIN,
    ROW_HEAD_W,
    SHEETS_DIR,
    TEXT_SIZE,
    TEXT_SRGB,
    TITLE_SIZE,
    UNFINISHED_SRGB,
    Arrangement,
    Grid,
    JobInfo,
    JobState,
    RunInfo,
    SheetResult,
)
from .read import scan_run

# drawing

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
    for i, part in enumerate(parts):  # noqa: B007 (i, read after the loop's break, counts the parts left out)
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
    for job in jobs:
        exr = job.file(RENDER_EXR)
        size = image_size(exr) if exr is not None else None
        if size is not None:
            return size[1] / size[0]
    return DEFAULT_ASPECT


def cell_render(job: JobInfo, cell_width: int) -> tuple[Path | None, str | None]:
    """The EXR a cell of ``cell_width`` pixels shows, and the name of its view if not the main one.

    The main render, unless its densest icicles (``icicle_px`` of view 0 in
    ``views.json``) would be under `ICE_VIEW_BELOW_PX` pixels wide at the cell's size and
    the job has an ice view (``frame: ice``) rendered: then that view.
    """
    exr = job.file(RENDER_EXR)
    views = job.views()
    if exr is None or not views:
        return exr, None
    px = views[0].get("icicle_px")
    if isinstance(px, bool) or not isinstance(px, (int, float)) or not math.isfinite(px):
        return exr, None
    size = image_size(exr)
    width = size[0] if size else None
    if width is None or px * cell_width / width >= ICE_VIEW_BELOW_PX:
        return exr, None
    for view in views[1:]:
        stem = view.get("stem")
        if view.get("frame") == "ice" and isinstance(stem, str) and "/" not in stem:
            zoomed = job.file(f"{stem}.exr")
            if zoomed is not None:
                return zoomed, str(view.get("name") or "ice")
    return exr, None


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
        message = error_line(job.folder.message, f"no {ERROR} message")
        _placeholder(buf, x, y, cw, ch, FAILED_SRGB, "FAILED",
                     [_clip(f"stage: {job.folder.failed_stage}", inner, 12)]
                     + _wrap(message.split(), inner, 12, 3, sep=" "))
        drawn = "failed"
    elif exr is None:
        reason = ("done, but no render (no render config, or --until)" if job.state is JobState.DONE
                  else f"unfinished: no {DONE}" if job.path is not None else "not run: no job folder")
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
    parts = [assignment(k, job.values[k]) for k in keys] or [f"job {job.job_id}"]
    lines = _wrap(parts, cw - 4, LABEL_SIZE, 2)
    if keys and any(line.endswith(("...", "more)")) for line in lines):  # too long: paper symbols
        lines = _wrap([compact_assignment(k, job.values[k]) for k in keys], cw - 4, LABEL_SIZE, 2)
    values_lines = len(lines)
    if len(lines) < 2:
        seconds = job.seconds
        status = {"render": "", "failed": f"failed at {job.folder.failed_stage}",
                  "not rendered": "not rendered", "unreadable": "render unreadable"}[drawn]
        if drawn == "render" and job.state is JobState.PENDING:
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
        axes = f"rows: {axis_title(grid.row_key)}   ×   columns: {axis_title(grid.col_key)}"
    elif grid.arrangement is Arrangement.ROW:
        axes = f"varying: {axis_title(grid.varying[0])}"
    elif grid.varying:
        axes = "grid in job order, varying: " + ", ".join(axis_title(k) for k in grid.varying)
    else:
        axes = "no parameter varies between these jobs"
    _text(buf, x, y, _clip(axes, inner, TEXT_SIZE), TEXT_SIZE, TEXT_SRGB)
    y += 20
    fixed = fixed_changes(jobs, grid.varying)
    if fixed:
        parts = [assignment(k, v) for k, v in fixed.items()]
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
        text = _clip(assignment(grid.col_key, value), cw, TEXT_SIZE, FONT_BOLD)
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
    write_run_gallery(run, sheets)
    return sheets
