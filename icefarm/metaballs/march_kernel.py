"""Marching cubes over a sparse block field, compiled, on every core (`icefarm.metaballs.cube_cases`).

Each block is marched on its own, its upper neighbours' first sample planes read as a halo,
in two passes (count, then fill) over batches of blocks in threads (the kernels leave the
GIL). Each crossed lattice edge of a block gets one vertex, placed in float64 from the
edge's two samples alone: an edge gets the same bits in every block and every marching
that holds it, which the seams and `icefarm.metaballs.fuse_fields` weld on.

scikit-image's marching cubes holds the GIL and knows no blocks: it needs the blocks
copied with their halos into one packed volume, masked between blocks, and its vertices
put back on their lattice edges. On 4,145 blocks of 600 random balls (1.5 M faces),
`march_blocks` takes 0.35-0.38 s with this kernel against 0.83-1.28 s through
scikit-image (medians of 5, three alternated rounds, 2 cores); `tests/test_march_kernel.py`
compares the two.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..compiled import compiled
from .balls import KAPPA
from .cube_cases import EDGES, cube_cases
from .field import CUTOFF

# Marching cubes interpolates F ** MARCH_POWER along cell edges: with p = KAPPA^2 / 2 it has
# its inflection at the surface of a chain, so there it is nearly exact. The field is
# clamped at CUTOFF * level first.
MARCH_POWER = KAPPA**2 / 2
# Edge ends closer than this (relative, after the power) to the level are pushed off it, so
# no vertex lands on a grid corner (which would make zero-area faces).
_NUDGE = 1e-3
# Blocks per batch of the threads: enough batches to keep every core busy.
_BATCH = 64


def march_slotted(values: np.ndarray, slots: np.ndarray, blocks: np.ndarray, level: float):
    """The cells of the blocks ``blocks``, each with its upper neighbours' samples as a halo.

    Parameters
    ----------
    values : (n, B, B, B) float32
        The field's blocks; inside is above ``level``.
    slots : (k, 8) int64
        Per block to march, the row of ``values`` holding it (column 0) and its upper
        neighbours (column ``dx + 2 dy + 4 dz``), -1 for none (zero).
    blocks : (k, 3) int64
        Their block coordinates: sample ``s`` of block ``b`` is lattice sample ``b * B + s``.
    level : float

    Returns
    -------
    lattice : (m, 3) float64
        Vertices in lattice coordinates, one per crossed lattice edge of each block.
    faces : (f, 3) int64
        Outward-wound (normals point to lower field).
    edge : (m,) int64
        For a vertex on a block's boundary plane (where blocks share edges), the lattice
        edge it lies on, numbered alike in every block; -1 elsewhere.
    """
    cases = cube_cases()
    b = values.shape[1]
    k = len(slots)
    codes = np.empty((k, b, b, b), dtype=np.uint8)
    counts = np.zeros((k, 2), dtype=np.int64)
    batches = [slice(i, min(i + _BATCH, k)) for i in range(0, k, _BATCH)]
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        list(pool.map(lambda s: _count(values, slots[s], float(level), cases.n_triangles, codes[s], counts[s]),
                      batches))
        starts = np.zeros((k + 1, 2), dtype=np.int64)
        np.cumsum(counts, axis=0, out=starts[1:])
        lattice = np.empty((starts[-1, 0], 3), dtype=np.float64)
        faces = np.empty((starts[-1, 1], 3), dtype=np.int64)
        edge = np.empty(starts[-1, 0], dtype=np.int64)
        # seam edges are numbered from the lowest sample of the marched blocks
        lo = blocks.min(axis=0) * b if k else np.zeros(3, np.int64)
        span = (blocks.max(axis=0) + 1) * b + 1 - lo if k else np.ones(3, np.int64)
        if int(span[0]) * int(span[1]) * int(span[2]) * 3 >= 2**63:
            raise ValueError(f"blocks {blocks.min(axis=0)} to {blocks.max(axis=0)} span too many samples to number "
                             "their seam edges in int64")
        grid = np.array([lo[0], lo[1], lo[2], span[1], span[2]], dtype=np.int64)
        edges = EDGES.astype(np.int64)
        list(pool.map(lambda s: _fill(values, slots[s], blocks[s], float(level), codes[s], starts[s],
                                      cases.triangles, cases.n_triangles, edges, grid, lattice, faces, edge),
                      batches))
    return lattice, faces, edge


@compiled(inline="always")
def _halo(values, slots, q, out):
    """Block ``q``'s samples and its upper neighbours' first planes into ``out`` (B+1)^3."""
    b = values.shape[1]
    for o in range(8):
        s = slots[q, o]
        ox, oy, oz = o & 1, o >> 1 & 1, o >> 2 & 1
        for i in range(b if ox == 0 else 1):
            for j in range(b if oy == 0 else 1):
                for k in range(b if oz == 0 else 1):
                    out[i + ox * b, j + oy * b, k + oz * b] = values[s, i, j, k] if s >= 0 else 0.0


@compiled()
def _count(values, slots, level, n_triangles, codes, counts):
    """Each cell's case into ``codes`` (k, B, B, B); each block's crossed edges and faces
    into ``counts`` (k, 2)."""
    b = values.shape[1]
    n1 = b + 1
    f = np.empty((n1, n1, n1), dtype=np.float32)
    inside = np.empty((n1, n1, n1), dtype=np.uint8)
    for q in range(slots.shape[0]):
        _halo(values, slots, q, f)
        for i in range(n1):
            for j in range(n1):
                for k in range(n1):
                    inside[i, j, k] = f[i, j, k] > level
        edges = 0
        for i in range(n1):
            for j in range(n1):
                for k in range(b):
                    edges += inside[i, j, k] != inside[i, j, k + 1]
        for i in range(n1):
            for j in range(b):
                for k in range(n1):
                    edges += inside[i, j, k] != inside[i, j + 1, k]
        for i in range(b):
            for j in range(n1):
                for k in range(n1):
                    edges += inside[i, j, k] != inside[i + 1, j, k]
        tris = 0
        if edges:
            for i in range(b):
                for j in range(b):
                    for k in range(b):
                        case = (inside[i, j, k] | inside[i + 1, j, k] << 1 | inside[i, j + 1, k] << 2
                                | inside[i + 1, j + 1, k] << 3 | inside[i, j, k + 1] << 4
                                | inside[i + 1, j, k + 1] << 5 | inside[i, j + 1, k + 1] << 6
                                | inside[i + 1, j + 1, k + 1] << 7)
                        codes[q, i, j, k] = case
                        tris += n_triangles[case]
        counts[q, 0] = edges
        counts[q, 1] = tris


@compiled()
def _fill(values, slots, blocks, level, codes, starts, triangles, n_triangles, edges, grid, lattice, faces, edge):
    """The vertices and faces `_count` counted, from ``starts`` (k + 1, 2) on."""
    b = values.shape[1]
    n1 = b + 1
    f = np.empty((n1, n1, n1), dtype=np.float32)
    ids = np.empty((3, n1, n1, n1), dtype=np.int64)
    t_level = level**MARCH_POWER
    floor = CUTOFF * level
    nudge = _NUDGE * t_level
    for q in range(slots.shape[0]):
        v = starts[q, 0]
        if starts[q + 1, 0] == v:
            continue
        _halo(values, slots, q, f)
        for axis in range(3):
            di, dj, dk = int(axis == 0), int(axis == 1), int(axis == 2)
            for i in range(n1 - di):
                for j in range(n1 - dj):
                    for k in range(n1 - dk):
                        a, c = f[i, j, k], f[i + di, j + dj, k + dk]
                        if (a > level) == (c > level):
                            continue
                        g0 = _domain(a, a > level, t_level, floor, nudge)
                        g1 = _domain(c, c > level, t_level, floor, nudge)
                        t = (t_level - g0) / (g1 - g0)
                        on_seam = False
                        for e in range(3):
                            local = (i, j, k)[e] + t if e == axis else np.float64((i, j, k)[e])
                            lattice[v, e] = blocks[q, e] * b + local
                            on_seam |= local == 0.0 or local == b
                        edge[v] = -1
                        if on_seam:
                            x = blocks[q, 0] * b + i - grid[0]
                            y = blocks[q, 1] * b + j - grid[1]
                            z = blocks[q, 2] * b + k - grid[2]
                            edge[v] = ((x * grid[3] + y) * grid[4] + z) * 3 + axis
                        ids[axis, i, j, k] = v
                        v += 1
        m = starts[q, 1]
        for i in range(b):
            for j in range(b):
                for k in range(b):
                    case = codes[q, i, j, k]
                    for t in range(n_triangles[case]):
                        for s in range(3):
                            e = triangles[case, t, s]
                            c = edges[e, 0]
                            faces[m, s] = ids[e // 4, i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)]
                        m += 1


@compiled(inline="always")
def _domain(value, inside, t_level, floor, nudge):
    """A sample's value on the marching domain: ``max(value, floor) ** MARCH_POWER``, at
    least ``nudge`` off ``t_level`` on its own side (a function of the one value, so blocks
    that share a sample cannot disagree on it)."""
    g = max(np.float64(value), floor) ** MARCH_POWER
    return max(g, t_level + nudge) if inside else min(g, t_level - nudge)
