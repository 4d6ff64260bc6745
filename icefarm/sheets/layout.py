"""Where the cells go: the grid of a sweep and the pixel geometry of a sheet."""

from __future__ import annotations

import math
from collections.abc import Sequence

from .labels import canonical, sort_key
from .model import (
    COL_HEAD_H,
    GAP,
    HEADER_H,
    LABEL_H,
    MARGIN,
    MIN_WIDTH,
    ROW_HEAD_W,
    WRAP_AFTER,
    Arrangement,
    Grid,
    JobInfo,
)

# grid

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
        pairs = [(canonical(j.values.get(row_key, missing)), canonical(j.values.get(col_key, missing))) for j in jobs]
        row_values = _distinct(jobs, row_key)
        col_values = _distinct(jobs, col_key)
        complete = all(row_key in j.values and col_key in j.values for j in jobs)
        if complete and len(set(pairs)) == n and len(row_values) * len(col_values) <= 2 * n:
            rindex = {canonical(v): i for i, v in enumerate(row_values)}
            cindex = {canonical(v): i for i, v in enumerate(col_values)}
            slots = [(rindex[canonical(j.values[row_key])], cindex[canonical(j.values[col_key])], j) for j in jobs]
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
            values.setdefault(canonical(j.values[key]), j.values[key])
    return sorted(values.values(), key=sort_key)


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
