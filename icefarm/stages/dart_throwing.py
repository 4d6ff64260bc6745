"""Dart throwing: the first points of a sequence that keep a least distance from each other."""

from __future__ import annotations

import numpy as np

from ..compiled import compiled


def spaced(points: np.ndarray, spacing: float, count: int) -> np.ndarray:
    """Indices of the first points, in order, that lie ``spacing`` or more from every one kept
    before them (dart throwing), at most ``count``.

    Kept points are binned in cells ``spacing`` wide, so each candidate is compared with the
    few kept in the 27 cells around it: linear in the candidates (50,000 along a long rim),
    where comparing with every kept point grew with their product. Compiled (`_dart_throw`):
    20,000 candidates in a thin slab, 19,000 kept, 0.055 s against 0.19 s in Python (medians
    of three); the test compares it with throwing against every kept point."""
    if spacing <= 0:
        return np.arange(min(count, len(points)))
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    cells = np.floor(points / spacing).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    occupied = np.unique(key)
    return _dart_throw(points, cells, span, np.searchsorted(occupied, key), occupied, spacing * spacing, int(count))


@compiled()
def _dart_throw(points, cells, span, cell, occupied, limit, count):
    """`spaced` on ``points`` (n, 3) in ``cells`` (n, 3, from 0 to ``span`` - 1): ``cell``
    (n,) each point's place in ``occupied``, the sorted keys of the cells that hold one. The
    points kept in a cell are a list threaded through ``after`` from its last one."""
    last = np.full(len(occupied), -1, dtype=np.int64)
    after = np.full(len(points), -1, dtype=np.int64)
    chosen = np.empty(min(count, len(points)), dtype=np.int64)
    kept = 0
    for i in range(len(points)):
        if kept == count:
            break
        close = False
        for a in range(-1, 2):
            cx = cells[i, 0] + a
            for b in range(-1, 2):
                cy = cells[i, 1] + b
                for c in range(-1, 2):
                    cz = cells[i, 2] + c
                    if close or min(cx, cy, cz) < 0 or cx >= span[0] or cy >= span[1] or cz >= span[2]:
                        continue
                    key = (cx * span[1] + cy) * span[2] + cz
                    at = np.searchsorted(occupied, key)
                    q = last[at] if at < len(occupied) and occupied[at] == key else -1
                    while q >= 0 and not close:
                        close = ((points[q, 0] - points[i, 0]) ** 2 + (points[q, 1] - points[i, 1]) ** 2
                                 + (points[q, 2] - points[i, 2]) ** 2) < limit
                        q = after[q]
        if close:
            continue
        after[i] = last[cell[i]]
        last[cell[i]] = i
        chosen[kept] = i
        kept += 1
    return chosen[:kept]
