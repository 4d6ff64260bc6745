"""The local union's bookkeeping over the whole meshes (`icefarm.metaballs.fuse`), compiled.

The union itself runs on a few per cent of the faces; sorting the rest (which face lies in
the region, which vertex joins a seam, which face stays) reads every face of both meshes.
In NumPy that took a dozen full passes, each gathering or copying a whole face array; here
each question is one loop over the faces.
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled

INNER, OUTER = 1, 2  # `vertex_sides` bits: a vertex of an inner face, of another face


@compiled()
def vertex_sides(faces: np.ndarray, inner: np.ndarray, n: int) -> np.ndarray:
    """``(n,) uint8``: per vertex, `INNER` if a face flagged in ``inner`` ``(m,) bool`` uses
    it, `OUTER` if another face does (both: a vertex of the region's seam)."""
    out = np.zeros(n, dtype=np.uint8)
    for f in range(len(faces)):
        bit = INNER if inner[f] else OUTER
        for k in range(3):
            out[faces[f, k]] |= bit
    return out


@compiled()
def kept_outside(faces: np.ndarray, inner: np.ndarray, covered: np.ndarray):
    """The faces ``(m, 3)`` out of the region (not ``inner``) that keep no corner in the
    other solid (``covered``, per vertex), in order, and whether any face out of the region
    lies partly inside it (the nearest-sample test then cannot decide: no union here)."""
    keep = np.zeros(len(faces), dtype=np.bool_)
    split = False
    for f in range(len(faces)):
        if inner[f]:
            continue
        count = 0
        for k in range(3):
            count += covered[faces[f, k]]
        if count == 0:
            keep[f] = True
        elif count < 3:
            split = True
    out = np.empty((keep.sum(), 3), dtype=faces.dtype)
    j = 0
    for f in range(len(faces)):
        if keep[f]:
            out[j] = faces[f]
            j += 1
    return out, split


@compiled()
def welded(parts, offsets, index: np.ndarray):
    """The faces of ``parts`` (a tuple of ``(m_i, 3)`` int64) shifted by ``offsets`` (one
    per part) and renumbered by ``index`` (one vertex list for all), and whether a face lost
    a corner to the welding (two corners on one vertex)."""
    total = 0
    for p in parts:
        total += len(p)
    out = np.empty((total, 3), dtype=np.int64)
    degenerate = False
    j = 0
    for i in range(len(parts)):
        p, off = parts[i], offsets[i]
        for f in range(len(p)):
            a, b, c = index[p[f, 0] + off], index[p[f, 1] + off], index[p[f, 2] + off]
            degenerate |= (a == b) | (b == c) | (a == c)
            out[j, 0], out[j, 1], out[j, 2] = a, b, c
            j += 1
    return out, degenerate


@compiled()
def compacted(faces: np.ndarray, n: int):
    """``faces`` renumbered over the vertices they use (of ``n``), and those vertices,
    ``(k,)`` int64 in order: ``vertices[used]`` and ``faces`` then go together."""
    new = np.full(n, -1, dtype=np.int64)
    for f in range(len(faces)):
        for k in range(3):
            new[faces[f, k]] = 0
    used = np.empty(n, dtype=np.int64)
    k = 0
    for v in range(n):
        if new[v] == 0:
            new[v] = k
            used[k] = v
            k += 1
    out = np.empty_like(faces)
    for f in range(len(faces)):
        for c in range(3):
            out[f, c] = new[faces[f, c]]
    return out, used[:k]
