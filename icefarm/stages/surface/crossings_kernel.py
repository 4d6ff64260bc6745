"""Where the ice mesh's edges cross the planes across the icicles' axes, compiled: the one
pass over every face of `icefarm.stages.surface.measure`'s slab radius (`_crossings`).

In NumPy the pass took a dozen whole-array steps over the faces and their edges (0.69 s of
the car's 1.96 s of icicle measures, py-spy); here it is one loop, counted, then filled.
"""

from __future__ import annotations

import math

import numpy as np

from ...compiled import compiled


@compiled()
def edge_crossings(faces, vertex, trunk_points, axis):
    """``(sample, radius)`` of each point where an edge of ``faces`` (m, 3) crosses the plane
    across the axis at an axis sample, as `icefarm.stages.surface.measure._crossings`
    gives them, in the same order (face by face, its edges (0, 1), (1, 2), (2, 0)).

    ``vertex``: ``(s, r, t)``, per mesh vertex its arc length along its trunk, its distance
    from the axis and its trunk (-1: not near an axis); ``trunk_points``: ``(first, count)``,
    per trunk its first sample and how many it has; ``axis``: ``(x, step)``, the samples'
    arc lengths and their spacing.
    """
    s, r, t = vertex
    first, points = trunk_points
    x, step = axis
    total = 0
    for pass_ in range(2):
        if pass_ == 1:
            owner = np.empty(total, dtype=np.int64)
            radial = np.empty(total, dtype=np.float64)
            total = 0
        for f in range(len(faces)):
            if t[faces[f, 0]] < 0 or t[faces[f, 1]] < 0 or t[faces[f, 2]] < 0:
                continue
            for k in range(3):
                a, b = faces[f, k], faces[f, (k + 1) % 3]
                # an edge shared by two faces runs once each way: the way up the trunk
                if t[a] != t[b] or not s[a] < s[b]:
                    continue
                start = first[t[a]]
                x0 = x[start]
                lo = max(np.int64(math.floor((s[a] - x0) / step)) + 1, 0)
                hi = min(np.int64(math.floor((s[b] - x0) / step)), points[t[a]] - 1)
                if pass_ == 0:
                    total += max(hi - lo + 1, 0)
                    continue
                for j in range(lo, hi + 1):
                    w = (x0 + j * step - s[a]) / (s[b] - s[a])
                    owner[total] = start + j
                    radial[total] = r[a] + w * (r[b] - r[a])
                    total += 1
    return owner, radial
