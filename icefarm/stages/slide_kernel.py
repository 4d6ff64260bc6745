"""The trajectory stage's slides (paper 4.3.1), compiled: a turtle that meets the object
follows its surface along gravity, step by step, until the drip criterion holds.

Each step casts two rays (back onto the surface, and along the chord to the new point). In
NumPy over the few turtles sliding at once, each step costs about 120 us, nearly all of it
per-call overhead: on Table 2's row f (480 steps a run) the slides take 63-73 ms a run. Here
each turtle slides to its end in one compiled loop, casting into an
`icefarm.triangle_tree.TriangleTree`: 11-15 ms (per-function timers over six runs, alternated;
tests/test_slide_kernel.py keeps the NumPy slides as the reference).
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled
from ..triangle_tree import STACK_SIZE, first_hit

DRIPS, ENDS = 1, 0  # how a slide ends: the turtle drips again from its end point, or stops


@compiled()
def slide_paths(start, normal, walk, face_normals, closed, tree):
    """Slide each turtle from ``start`` (k, 3), lifted ``lift`` off the surface whose
    normal is ``normal`` (k, 3), for at most ``limit`` steps of ``step`` (meters), over the
    mesh of ``tree`` (`icefarm.triangle_tree.TriangleTree.arrays`) and its ``face_normals``.
    ``walk`` is ``(g, cos_dl, step, lift, eps, limit)``: gravity (3,) unit, the cosine of
    the drip limit, and the step, lift and ray offset in meters.

    A step goes down the tangent plane, then a ray back along the normal puts the point on
    the surface again (a point whose surface falls away beneath it drips from there); the
    chord to the new point must not cut through the object (where it would, the slide stops
    short of that wall and follows it next), and it must descend (else the water pools: the
    turtle stops). The slide drips where ``normal . g >= cos_dl``. ``closed``: the mesh is
    watertight (otherwise a face's normal is turned to the side the turtle comes from).

    Returns
    -------
    points : (p, 3) float
        The points each step reached, turtle after turtle.
    owner : (p,) int
        The turtle of each point.
    end : (k, 3) float
        Where each turtle that drips again does so.
    outcome : (k,) int8
        `DRIPS` or `ENDS`.
    """
    g, cos_dl, step, lift, eps, limit = walk
    k = len(start)
    outcome = np.full(k, ENDS, dtype=np.int8)
    end = start.copy()
    points = np.empty((max(16, 4 * k), 3))
    owner = np.empty(len(points), dtype=np.int64)
    count = 0
    stack = np.empty(STACK_SIZE, dtype=np.int64)
    back_dir = np.empty(3)
    chord_dir = np.empty(3)
    for r in range(k):
        p = start[r].copy()
        n = normal[r].copy()
        for _ in range(limit):
            ndg = n[0] * g[0] + n[1] * g[1] + n[2] * g[2]
            if ndg >= cos_dl:
                outcome[r] = DRIPS
                end[r] = p
                break
            along = g - ndg * n
            size = np.sqrt(along[0] ** 2 + along[1] ** 2 + along[2] ** 2)
            if size < 1e-3:  # stuck: no way down along the surface
                break
            target = p + (step / size) * along
            for a in range(3):
                back_dir[a] = -n[a]
            back, below = first_hit(target, back_dir, stack, tree)
            fell = back > step + lift
            new_n = n.copy()
            moved = target.copy()
            if not fell:
                new_n = _facing(face_normals, below, back_dir, closed)
                moved = target - back * n + lift * new_n
            chord = moved - p
            span = np.sqrt(chord[0] ** 2 + chord[1] ** 2 + chord[2] ** 2)
            if span > 0.0:
                for a in range(3):
                    chord_dir[a] = chord[a] / span
                reach, wall = first_hit(p, chord_dir, stack, tree)
                if reach < span + eps:
                    moved = p + max(reach - lift, 0.0) * chord_dir
                    new_n = _facing(face_normals, wall, chord, closed)
                    fell = False
            if (moved[0] - p[0]) * g[0] + (moved[1] - p[1]) * g[1] + (moved[2] - p[2]) * g[2] < 0.05 * step:
                break  # it does not descend: the water pools here
            p = moved
            n = new_n
            if count == len(points):
                points = _grown(points)
                owner = _grown(owner)
            points[count] = p
            owner[count] = r
            count += 1
            if fell:
                outcome[r] = DRIPS
                end[r] = p
                break
    return points[:count], owner[:count], end, outcome


@compiled()
def _facing(face_normals, face, towards, closed):
    """The unit normal of ``face``, turned (on an open mesh) to the side ``towards`` points from."""
    out = face_normals[face].copy()
    if not closed and out[0] * towards[0] + out[1] * towards[1] + out[2] * towards[2] > 0.0:
        out = -out
    return out


@compiled()
def _grown(a):
    out = np.empty((2 * len(a),) + a.shape[1:], dtype=a.dtype)
    out[:len(a)] = a
    return out
