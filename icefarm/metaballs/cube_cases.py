"""The 256 marching-cubes cases of a cell, triangulated so that neighbouring cells agree.

A cell's corner ``c`` sits at ``(c & 1, c >> 1 & 1, c >> 2 & 1)``; a case is the set of its
corners inside the surface (bit ``c``). On each face of the cell the crossed edges are
paired: two crossings join each other, four (an ambiguous face, inside corners diagonal)
join around each outside corner, so the inside stays connected across the face. The rule
reads only the face's four corners, so the two cells sharing a face draw the same segments
on it: the cells' surfaces close on each other (watertight), and every crossed edge has
one segment on each of its two faces, so the segments form loops, each a disk of its own
(a 2-manifold). Each loop is wound so that its normal points out (to the corners outside)
and cut into a fan of triangles from the vertex that gives the roundest triangles, none
lying in a face of the cell (where a loop crosses a face twice, such a triangle could lie
on a neighbour's). Every loop of the 256 cases has such a fan: loops have 3 to 7 vertices,
a case at most 5 triangles, and no vertex lies inside a cell.

The tables are built once per process from this rule.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

# Edge e joins corners EDGES[e]; it runs along axis e // 4 from its first corner.
_EDGE_CORNERS = ((0, 1), (2, 3), (4, 5), (6, 7),
                 (0, 2), (1, 3), (4, 6), (5, 7),
                 (0, 4), (1, 5), (2, 6), (3, 7))
EDGES = np.array(_EDGE_CORNERS)
# Each face's corners in cyclic order.
_FACES = ((0, 2, 6, 4), (1, 3, 7, 5), (0, 1, 5, 4), (2, 3, 7, 6), (0, 1, 3, 2), (4, 5, 7, 6))
# Most triangles one case makes.
MAX_TRIANGLES = 5


@dataclass(frozen=True)
class CubeCases:
    """The triangulation of each of the 256 cases.

    Attributes
    ----------
    triangles : (256, MAX_TRIANGLES, 3) int8
        Each triangle's vertices, by the edge (0-11) they lie on.
    n_triangles : (256,) int8
    """

    triangles: np.ndarray
    n_triangles: np.ndarray


def _corner(c: int) -> tuple[int, int, int]:
    return c & 1, c >> 1 & 1, c >> 2 & 1


@functools.cache
def _midpoint(e: int) -> tuple[float, float, float]:
    a, b = (_corner(c) for c in _EDGE_CORNERS[e])
    return (a[0] + b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2


_EDGE_OF = {frozenset(pair): e for e, pair in enumerate(_EDGE_CORNERS)}
_FACE_SETS = tuple(frozenset(face) for face in _FACES)


def _segments(case: int) -> list[tuple[int, int]]:
    """The pairs of crossed edges joined on each face."""
    inside = [bool(case >> c & 1) for c in range(8)]
    pairs = []
    for face in _FACES:
        ring = [_EDGE_OF[frozenset((face[i], face[(i + 1) % 4]))] for i in range(4)]
        crossed = [i for i in range(4) if inside[face[i]] != inside[face[(i + 1) % 4]]]
        if len(crossed) == 2:
            pairs.append((ring[crossed[0]], ring[crossed[1]]))
        elif len(crossed) == 4:  # cut off each outside corner: edges i - 1 and i meet at corner i
            pairs += [(ring[i - 1], ring[i]) for i in range(4) if not inside[face[i]]]
    return pairs


def _loops(case: int) -> list[list[int]]:
    """The cycles of crossed edges the face segments make."""
    links: dict[int, list[int]] = {}
    for a, b in _segments(case):
        links.setdefault(a, []).append(b)
        links.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in sorted(links):
        if start in seen:
            continue
        loop, prev, at = [start], None, start
        seen.add(start)
        while True:
            nxt = links[at][0] if links[at][0] != prev else links[at][1]
            if nxt == start:
                break
            loop.append(nxt)
            seen.add(nxt)
            prev, at = at, nxt
        loops.append(loop)
    return loops


def _sub(a, b):
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def _cross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _outward(loop: list[int], case: int) -> list[int]:
    """The loop wound so that its normal (Newell's, over the edges' midpoints) points from
    its edges' inside corners to their outside ones."""
    mid = [_midpoint(e) for e in loop]
    normal = [0.0, 0.0, 0.0]
    for p, q in zip(mid, mid[1:] + mid[:1]):
        normal = [n + c for n, c in zip(normal, _cross(p, q))]
    out = [0.0, 0.0, 0.0]
    for e in loop:
        a, b = _EDGE_CORNERS[e]
        step = _sub(_corner(b), _corner(a)) if case >> a & 1 else _sub(_corner(a), _corner(b))
        out = [o + d for o, d in zip(out, step)]
    side = _dot(normal, out)
    if side == 0:
        raise AssertionError(f"case {case}: a loop without a direction")
    return loop if side > 0 else loop[::-1]


def _in_one_face(edges) -> bool:
    """Whether the edges all lie on one face of the cell."""
    corners = frozenset(c for e in edges for c in _EDGE_CORNERS[e])
    return any(corners <= face for face in _FACE_SETS)


def _fan(loop: list[int]) -> list[tuple[int, int, int]]:
    """The fan whose worst triangle (area over squared perimeter, over the edges' midpoints)
    is roundest, of those with no triangle in one face."""
    n = len(loop)
    best, best_quality = None, -1.0
    for root in range(n):
        fan = [(loop[root], loop[(root + i) % n], loop[(root + i + 1) % n]) for i in range(1, n - 1)]
        if any(_in_one_face(t) for t in fan):
            continue
        quality = min(_roundness(*(_midpoint(e) for e in t)) for t in fan)
        if quality > best_quality + 1e-12:
            best, best_quality = fan, quality
    if best is None:
        raise AssertionError(f"loop {loop}: every fan has a triangle in a face")
    return best


def _roundness(a, b, c) -> float:
    area = _dot(n := _cross(_sub(b, a), _sub(c, a)), n) ** 0.5 / 2
    perimeter = sum(_dot(d, d) ** 0.5 for d in (_sub(b, a), _sub(c, b), _sub(a, c)))
    return area / perimeter**2


@functools.cache
def cube_cases() -> CubeCases:
    """The tables (`CubeCases`), built on first use."""
    triangles = np.zeros((256, MAX_TRIANGLES, 3), dtype=np.int8)
    n_triangles = np.zeros(256, dtype=np.int8)
    for case in range(1, 255):
        tris = [t for loop in _loops(case) for t in _fan(_outward(loop, case))]
        triangles[case, :len(tris)] = tris
        n_triangles[case] = len(tris)
    return CubeCases(triangles, n_triangles)
