"""The turtle that draws icicle trajectories (stage 3, paper 4.3): its state, its moves
(``+`` bend, ``/`` roll, ``F`` step, the branch departure) and the collisions (4.3.1): a
step that would cross the object slides along its surface until the drip criterion holds.

`icefarm.stages.trajectories.grow_trajectories` rewrites the L-system and drives it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import perpendicular_basis, unit
from ..spatial import ray_caster
from ..tol import tol
from ..triangle_tree import TriangleTree, triangle_tree
from .slide_kernel import DRIPS, ENDS, slide_paths

BRANCH_ANGLE = 30.0  # degrees: p1'' leaves the trunk at 30 degrees, then turns back parallel


@dataclass
class _Turtles:
    """Turtle states, one row per growing apex (an X or A symbol of the L-system)."""

    pos: np.ndarray        # (t, 3)
    heading: np.ndarray    # (t, 3) H
    left: np.ndarray       # (t, 3) L
    branch: np.ndarray     # (t,) int, the polyline each turtle extends
    icicle: np.ndarray     # (t,) int
    pending_a: np.ndarray  # (t,) bool, next rewrite is p2 (A), not X
    alive: np.ndarray      # (t,) bool, False once a trajectory ends against the object
    rest: np.ndarray       # (t,) int, generations a new branch waits: its spread used them
    last: np.ndarray       # (t,) int, generations it grows in all (a branch: its share of the water)

    def append(self, other: _Turtles) -> _Turtles:
        return _Turtles(*(np.concatenate([a, b]) for a, b in zip(vars(self).values(), vars(other).values())))

    def take(self, rows: np.ndarray) -> _Turtles:
        return _Turtles(*(a[rows].copy() for a in vars(self).values()))


def _rotate(a: np.ndarray, b: np.ndarray, degrees) -> tuple[np.ndarray, np.ndarray]:
    """Rotate the orthonormal pair ``(a, b)`` (rows) by ``degrees`` in their plane."""
    t = np.radians(np.asarray(degrees, dtype=np.float64))[..., None]
    return a * np.cos(t) + b * np.sin(t), b * np.cos(t) - a * np.sin(t)


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products ``(k,)`` of ``(k, 3)`` arrays."""
    return np.einsum("ij,ij->i", a, b)


def _across(v: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Unit part ``(k, 3)`` of ``v`` perpendicular to the unit rows ``h`` (any perpendicular if none)."""
    out = v - row_dot(v, h)[:, None] * h
    bad = np.linalg.norm(out, axis=1) < tol.zero
    if bad.any():
        out[bad] = [perpendicular_basis(x)[0] for x in h[bad]]
    return unit(out)


class _Grower:
    """Runs the turtles of one trajectory stage against one mesh (collisions, slides)."""

    def __init__(self, mesh, gravity, step, drip_limit, caster=None, max_tilt=90.0, wind=None, slide=True):
        self.mesh, self.g, self.step = mesh, unit(gravity), step
        self.slides = slide  # False: an icicle that meets the object ends there
        self.cos_dl = np.cos(np.radians(drip_limit))
        self.max_tilt = np.radians(max_tilt)
        self.wind = wind  # (3,) unit, perpendicular to gravity, or None for still air
        self.eps = tol.offset * float(np.linalg.norm(mesh.extents))
        # Slide points float this far off the surface so chords between them stay outside
        # curved parts (sagitta of a step on a 2 mm radius); the ice covers the gap.
        self.lift = max(self.eps, 0.25 * step)
        self.points: list[list[np.ndarray]] = []
        self.caster = caster or ray_caster(mesh)
        self.normals = np.ascontiguousarray(mesh.face_normals, dtype=np.float64)
        self.closed = bool(mesh.is_watertight)
        self.tree: TriangleTree | None = None  # for the slides, built at the first

    def bend(self, t: _Turtles, rows: np.ndarray, degrees: float) -> None:
        """``+(c)``: yaw H by ``degrees`` towards L, or towards the wind, saturating at max_tilt.

        The wind direction is taken perpendicular to H, so every icicle turns the same way
        whatever its roll; L then only spreads the branches.
        """
        if len(rows) == 0:
            return
        h, left = t.heading[rows], t.left[rows]
        if self.wind is None:
            towards = left
            new_h, new_l = _rotate(h, left, degrees)
        else:
            across = self.wind - (h @ self.wind)[:, None] * h
            towards = np.where((np.linalg.norm(across, axis=1) > tol.zero)[:, None], unit(across), left)
            new_h, new_t = _rotate(h, towards, degrees)
            # L's share of the turning plane turns with it (a rotation, so L stays unit and normal to H)
            new_l = left + row_dot(left, towards)[:, None] * (new_t - towards)
        new_h, changed = self.saturate(h, new_h, towards, soft=True)
        new_l[changed] = _across(new_l[changed], new_h[changed])
        t.heading[rows], t.left[rows] = new_h, new_l

    def saturate(self, h0: np.ndarray, h1: np.ndarray, towards: np.ndarray,
                 soft: bool) -> tuple[np.ndarray, np.ndarray]:
        """Headings ``h1`` ``(k, 3)`` turned from ``h0`` with their tilt from gravity bounded.

        ``soft`` scales a tilt increase by the room left, ``1 - tilt0 / max_tilt``: a steady
        bend then approaches max_tilt like a wind-bent icicle instead of passing it and
        winding up into a loop. Every result lies within max_tilt of gravity; the azimuth of
        ``h1`` is kept (that of ``towards`` where ``h1`` has none). Returns the headings and
        a ``(k,)`` mask of those changed.
        """
        tilt0 = np.arccos(np.clip(h0 @ self.g, -1.0, 1.0))
        tilt1 = np.arccos(np.clip(h1 @ self.g, -1.0, 1.0))
        tilt = tilt1
        if soft:
            room = np.clip(1.0 - tilt0 / self.max_tilt, 0.0, 1.0) if self.max_tilt > 0 else np.zeros_like(tilt0)
            tilt = np.where(tilt1 > tilt0, tilt0 + (tilt1 - tilt0) * room, tilt1)
        tilt = np.minimum(tilt, self.max_tilt)
        changed = tilt < tilt1 - 1e-12  # untouched rows keep their exact bits (c = 0 stays straight)
        if changed.any():
            h1 = h1.copy()
            side = h1[changed] - (h1[changed] @ self.g)[:, None] * self.g
            fallback = towards[changed] - (towards[changed] @ self.g)[:, None] * self.g
            side = np.where((np.linalg.norm(side, axis=1) > tol.zero)[:, None], side, fallback)
            side = _across(side, np.tile(self.g, (len(side), 1)))
            h1[changed] = (np.cos(tilt[changed])[:, None] * self.g + np.sin(tilt[changed])[:, None] * side)
        return h1, changed

    def depart(self, t: _Turtles, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``+(30)`` of p1'': point new branches 30 degrees off their heading, towards L.

        Where that would lean past max_tilt, the turn rolls around H to the nearest side
        that stays within it, keeping the full 30 degrees (clamping the tilt instead would
        lay the branch back onto its parent). Returns the headings and L ``(k, 3)`` before
        the turn, which ``-(30)`` restores.
        """
        h, left = t.heading[rows].copy(), t.left[rows].copy()
        out, normal = left.copy(), np.cross(h, left)
        s, c = np.sin(np.radians(BRANCH_ANGLE)), np.cos(np.radians(BRANCH_ANGLE))
        # the departure D = c H + s M has D.g = c H.g + s M.g; M(phi) = L cos phi + N sin phi
        a, b = left @ self.g, normal @ self.g
        need = (np.cos(self.max_tilt) - c * (h @ self.g)) / s
        over = a < need - 1e-12
        if over.any():
            rho, psi = np.hypot(a[over], b[over]), np.arctan2(b[over], a[over])
            # M.g = rho cos(phi - psi) >= need on |phi - psi| <= delta; none reach it: steepest
            delta = np.arccos(np.clip(np.divide(need[over], rho, out=np.ones_like(rho), where=rho > 0), -1.0, 1.0))
            phi = np.stack([psi + delta, psi - delta])
            phi = (phi + np.pi) % (2 * np.pi) - np.pi
            phi = np.take_along_axis(phi, np.argmin(np.abs(phi), axis=0)[None], axis=0)[0]
            out[over] = np.cos(phi)[:, None] * left[over] + np.sin(phi)[:, None] * normal[over]
        heading, new_l = _rotate(h, out, BRANCH_ANGLE)
        heading, changed = self.saturate(h, heading, out, soft=False)  # only when max_tilt < 30
        new_l[changed] = _across(new_l[changed], heading[changed])
        t.heading[rows], t.left[rows] = heading, new_l
        return h, left

    def roll(self, t: _Turtles, rows: np.ndarray, degrees) -> None:
        """``/(degrees)``: roll around H, turning L towards U = H x L."""
        up = np.cross(t.heading[rows], t.left[rows])
        t.left[rows], _ = _rotate(t.left[rows], up, degrees)

    def forward(self, t: _Turtles, rows: np.ndarray) -> np.ndarray:
        """``F`` for the turtles ``rows``: one step, or on collision with the object a slide
        along it (``slide``) or the end of the branch, its tip on the surface.

        Returns the rows that collided (and slid, dripped again or ended).
        """
        rows = rows[t.alive[rows]]
        if len(rows) == 0:
            return rows
        origin, heading = t.pos[rows], t.heading[rows]
        reach, face = self.cast(origin, heading)
        blocked = reach < self.step + self.eps
        free = rows[~blocked]
        t.pos[free] += self.step * t.heading[free]
        for r in free:
            self.points[t.branch[r]].append(t.pos[r].copy())
        if blocked.any():
            hits = origin[blocked] + reach[blocked, None] * heading[blocked]
            if self.slides:
                self.slide(t, rows[blocked], hits, face[blocked])
            else:  # its tip stops short of the surface it met by the slides' lift, on its course
                ends = blocked.copy()
                ends[blocked] = reach[blocked] > 2.0 * self.lift
                self.record(t, rows[ends], origin[ends] + (reach[ends] - self.lift)[:, None] * heading[ends])
                t.alive[rows[blocked]] = False
        return rows[blocked]

    def cast(self, origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance ``(k,)`` to the first hit along each ray (inf if none) and its face (-1)."""
        return self.caster(origin, direction)

    def facing(self, face: np.ndarray, towards: np.ndarray) -> np.ndarray:
        """Unit normals ``(k, 3)`` of ``face``, turned to the side ``towards`` points from."""
        normal = self.normals[face]
        if not self.closed:  # open meshes have no outside: face where we came from
            normal = np.where((np.einsum("ij,ij->i", normal, towards) > 0)[:, None], -normal, normal)
        return normal

    def slide(self, t: _Turtles, rows: np.ndarray, hits: np.ndarray, face: np.ndarray) -> None:
        """Follow the surface along gravity from ``hits`` until the drip criterion holds (4.3.1).

        Each turtle slides to its end in one compiled loop (`slide_kernel.slide_paths`): each
        step goes down the tangent plane, then a ray back along the normal puts the point on
        the surface again. A point whose surface falls
        away beneath it drips from there; one that stops descending (a floor, a pocket) ends.
        Every recorded point lies below the one before it: water never runs up.
        """
        normal = self.facing(face, t.heading[rows])
        pos = hits + self.lift * normal
        # A hit just below the turtle, lifted off an up-facing surface, can sit above it:
        # the slide then starts where the turtle stands (already outside, near the surface).
        rises = (pos - t.pos[rows]) @ self.g < 1e-3 * self.step
        pos[rises] = t.pos[rows[rises]]
        self.record(t, rows[~rises], pos[~rises])
        limit = int(4 * np.linalg.norm(self.mesh.extents) / self.step) + 1
        if self.tree is None:
            self.tree = triangle_tree(self.mesh.vertices, self.mesh.faces)
        walk = (self.g, float(self.cos_dl), float(self.step), float(self.lift), float(self.eps), limit)
        points, owner, end, outcome = slide_paths(np.ascontiguousarray(pos), np.ascontiguousarray(normal), walk,
                                                  self.normals, self.closed, self.tree.arrays())
        self.record(t, rows[owner], points)
        t.alive[rows[outcome == ENDS]] = False
        self.release(t, rows[outcome == DRIPS], end[outcome == DRIPS])

    def record(self, t: _Turtles, rows: np.ndarray, pos: np.ndarray) -> None:
        for r, p in zip(rows, pos):
            self.points[t.branch[r]].append(p.copy())

    def release(self, t: _Turtles, rows: np.ndarray, pos: np.ndarray) -> None:
        """Turtles ``rows`` drip again from ``pos``: they head along gravity from there."""
        if len(rows) == 0:
            return
        t.pos[rows] = pos
        left = t.left[rows] - (t.left[rows] @ self.g)[:, None] * self.g
        fallback = perpendicular_basis(self.g)[0]
        left = np.where((np.linalg.norm(left, axis=1) < 1e-6)[:, None], fallback, unit(left))
        t.heading[rows] = self.g
        t.left[rows] = left

    def new_branches(self, t: _Turtles, rows: np.ndarray) -> _Turtles:
        """Copies of turtles ``rows`` that start new polylines where they stand."""
        child = t.take(rows)
        child.branch = np.arange(len(self.points), len(self.points) + len(rows))
        child.pending_a[:] = False
        child.rest[:] = 0
        for r in rows:
            self.points.append([t.pos[r].copy()])
        return child
