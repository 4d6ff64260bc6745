"""The order that lays points out as the leaves of a complete binary tree, each node's
points split at its middle leaf across their widest extent (compiled): the trees of
surface samples (`icefarm.stages.surface.coat_kernel.PointTree`) and of triangles
(`icefarm.triangle_tree.TriangleTree`) are built on it, with their nodes' boxes."""

from __future__ import annotations

import numpy as np

from .compiled import compiled

_EXTENT_SAMPLES = 64  # points that pick the axis a node splits across


@compiled()
def median_order(points, leaves, leaf):
    """The order of ``points`` (n, 3) that puts node k's points (its leaves ``l0 .. l1``, of
    ``leaf`` points each) in rows ``l0 leaf .. l1 leaf``, its first child's (the first half
    of its leaves) on the low side of its widest axis. The points move with their rows
    (sequential reads)."""
    n = len(points)
    work = points.copy()
    order = np.arange(n)
    width = leaves
    while width > 1:
        half = width // 2
        for first in range(0, leaves, width):
            start, mid, end = min(first * leaf, n), min((first + half) * leaf, n), min((first + width) * leaf, n)
            if mid <= start or mid >= end:
                continue
            # the widest extent, of at most _EXTENT_SAMPLES of the points
            stride = max(1, (end - start) // _EXTENT_SAMPLES)
            axis, widest = 0, -1.0
            for a in range(3):
                low, high = np.inf, -np.inf
                for j in range(start, end, stride):
                    low = min(low, work[j, a])
                    high = max(high, work[j, a])
                if high - low > widest:
                    axis, widest = a, high - low
            _select(work, order, start, end, mid, axis)
        width = half
    return order


@compiled()
def _select(work, order, start, end, kth, axis):
    """Reorder rows ``start:end`` of ``work`` (and ``order`` with them) so that none before
    row ``kth`` lies above, along ``axis``, any from it on (quickselect, Hoare's partition
    about a median of three)."""
    lo, hi = start, end - 1
    while lo < hi:
        a, b, c = work[lo, axis], work[(lo + hi) // 2, axis], work[hi, axis]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi
        while i <= j:
            while work[i, axis] < pivot:
                i += 1
            while work[j, axis] > pivot:
                j -= 1
            if i <= j:
                for d in range(3):
                    work[i, d], work[j, d] = work[j, d], work[i, d]
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if kth <= j:
            hi = j
        elif kth >= i:
            lo = i
        else:
            break


@compiled()
def tree_boxes(shapes, leaves, leaf):
    """The boxes (lo, hi: (2 leaves, 3)) of leaves of ``leaf`` consecutive ``shapes``
    (n, c, 3: points with c = 1, triangles with c = 3) in `median_order`, and of the nodes
    above them (node k's children are 2k and 2k + 1); empty leaves' are inside out (inf, -inf)."""
    lo = np.full((2 * leaves, 3), np.inf)
    hi = np.full((2 * leaves, 3), -np.inf)
    for j in range(len(shapes)):
        k = leaves + j // leaf
        for v in range(shapes.shape[1]):
            for a in range(3):
                lo[k, a] = min(lo[k, a], shapes[j, v, a])
                hi[k, a] = max(hi[k, a], shapes[j, v, a])
    for k in range(leaves - 1, 0, -1):
        for a in range(3):
            lo[k, a] = min(lo[2 * k, a], lo[2 * k + 1, a])
            hi[k, a] = max(hi[2 * k, a], hi[2 * k + 1, a])
    return lo, hi
