"""Lookdev contact sheets (OpenImageIO) and an HTML gallery of one sweep folder.

Reads the job-folder contract (`icefarm.jobdir`)::

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

from .draw import build_sheet, build_sheets, cell_render, srgb_to_linear
from .gallery import write_gallery
from .labels import fixed_changes, format_value, short_name, varying_keys
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
                    HEADER_H,
                    ICE_VIEW_BELOW_PX,
                    LABEL_H,
                    LABEL_SIZE,
                    MARGIN,
                    MIN_WIDTH,
                    ROW_HEAD_W,
                    SHEETS_DIR,
                    TEXT_SIZE,
                    TEXT_SRGB,
                    TITLE_SIZE,
                    UNFINISHED_SRGB,
                    VIEWS_FILE,
                    WRAP_AFTER,
                    Arrangement,
                    Grid,
                    JobInfo,
                    JobState,
                    RunInfo,
                    SheetResult,
)
from .read import scan_run

__all__ = [
    "MARGIN", "GAP", "HEADER_H", "LABEL_H", "ROW_HEAD_W", "COL_HEAD_H", "MIN_WIDTH",
    "DEFAULT_ASPECT", "WRAP_AFTER", "ICE_VIEW_BELOW_PX", "VIEWS_FILE", "FIT_FILTER", "FONT",
    "FONT_BOLD", "TITLE_SIZE", "TEXT_SIZE", "LABEL_SIZE", "BACKGROUND_SRGB", "TEXT_SRGB",
    "DIM_TEXT_SRGB", "FAILED_SRGB", "UNFINISHED_SRGB", "EMPTY_SRGB", "SHEETS_DIR", "JobState",
    "Arrangement", "SheetResult", "JobInfo", "RunInfo", "Grid", "scan_run", "varying_keys",
    "fixed_changes", "short_name", "format_value", "plan_grid", "sheet_size", "cell_origin",
    "srgb_to_linear", "cell_render", "build_sheet", "build_sheets", "write_gallery",
]
