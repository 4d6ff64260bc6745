"""Stage 3 (paper 4.3): icicle trajectories from the L-system, with collisions (4.3.1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry import perpendicular_basis, ray_caster, unit


@dataclass(frozen=True)
class TrajectoryResult:
    """Icicle trajectories as polylines, one per branch, stored flat (CSR).

    Attributes
    ----------
    points : (p, 3) float
        All polyline points, in meters, branch after branch; each branch runs from its
        base (x = 0, at the drip point or where it leaves its parent) to its tip.
    branch_offsets : (b + 1,) int
        Branch ``i`` is ``points[branch_offsets[i]:branch_offsets[i + 1]]``.
    branch_icicle : (b,) int
        Icicle (= drip point index) of each branch.
    branch_parent : (b,) int
        Index of the parent branch, -1 for an icicle's trunk.
    """

    points: np.ndarray
    branch_offsets: np.ndarray
    branch_icicle: np.ndarray
    branch_parent: np.ndarray

    @property
    def n_branches(self) -> int:
        return len(self.branch_icicle)

    def branch(self, i: int) -> np.ndarray:
        """``(k, 3)`` points of branch ``i``."""
        return self.points[self.branch_offsets[i]:self.branch_offsets[i + 1]]


GOLDEN_ROLL = 137.5  # degrees: the plant-like spiral of the paper's roll (a = au * 137.5 / 360)
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

    def append(self, other: "_Turtles") -> "_Turtles":
        return _Turtles(*(np.concatenate([a, b]) for a, b in zip(vars(self).values(), vars(other).values())))

    def take(self, rows: np.ndarray) -> "_Turtles":
        return _Turtles(*(a[rows].copy() for a in vars(self).values()))


def _rotate(a: np.ndarray, b: np.ndarray, degrees) -> tuple[np.ndarray, np.ndarray]:
    """Rotate the orthonormal pair ``(a, b)`` (rows) by ``degrees`` in their plane."""
    t = np.radians(np.asarray(degrees, dtype=np.float64))[..., None]
    return a * np.cos(t) + b * np.sin(t), b * np.cos(t) - a * np.sin(t)


class _Grower:
    """Runs the turtles of one trajectory stage against one mesh (collisions, slides)."""

    def __init__(self, mesh, gravity, step, drip_limit, caster=None):
        self.mesh, self.g, self.step = mesh, unit(gravity), step
        self.cos_dl = np.cos(np.radians(drip_limit))
        self.eps = 1e-4 * float(np.linalg.norm(mesh.extents))
        # Slide points float this far off the surface so chords between them stay outside
        # curved parts (sagitta of a step on a 2 mm radius); the ice covers the gap.
        self.lift = max(self.eps, 0.25 * step)
        self.points: list[list[np.ndarray]] = []
        self.caster = caster or ray_caster(mesh)

    def turn(self, t: _Turtles, rows: np.ndarray, degrees) -> None:
        """``+(degrees)``: yaw around U, turning H towards L."""
        t.heading[rows], t.left[rows] = _rotate(t.heading[rows], t.left[rows], degrees)

    def roll(self, t: _Turtles, rows: np.ndarray, degrees) -> None:
        """``/(degrees)``: roll around H, turning L towards U = H x L."""
        up = np.cross(t.heading[rows], t.left[rows])
        t.left[rows], _ = _rotate(t.left[rows], up, degrees)

    def forward(self, t: _Turtles, rows: np.ndarray) -> None:
        """``F`` for the turtles ``rows``: one step, or a slide along the object on collision."""
        rows = rows[t.alive[rows]]
        if len(rows) == 0:
            return
        origin, heading = t.pos[rows], t.heading[rows]
        reach, face = self.cast(origin, heading)
        blocked = reach < self.step + self.eps
        free = rows[~blocked]
        t.pos[free] += self.step * t.heading[free]
        for r in free:
            self.points[t.branch[r]].append(t.pos[r].copy())
        if blocked.any():
            hits = origin[blocked] + reach[blocked, None] * heading[blocked]
            self.slide(t, rows[blocked], hits, face[blocked])

    def cast(self, origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance ``(k,)`` to the first hit along each ray (inf if none) and its face (-1)."""
        return self.caster(origin, direction)

    def facing(self, face: np.ndarray, towards: np.ndarray) -> np.ndarray:
        """Unit normals ``(k, 3)`` of ``face``, turned to the side ``towards`` points from."""
        normal = self.mesh.face_normals[face]
        if not self.mesh.is_watertight:  # open meshes have no outside: face where we came from
            normal = np.where((np.einsum("ij,ij->i", normal, towards) > 0)[:, None], -normal, normal)
        return normal

    def slide(self, t: _Turtles, rows: np.ndarray, hits: np.ndarray, face: np.ndarray) -> None:
        """Follow the surface along gravity from ``hits`` until the drip criterion holds (4.3.1).

        All sliding turtles move together: each step goes down the tangent plane, then a ray
        back along the normal puts the point on the surface again. A point whose surface falls
        away beneath it drips from there; one that stops descending (a floor, a pocket) ends.
        """
        normal = self.facing(face, t.heading[rows])
        pos = hits + self.lift * normal
        self.record(t, rows, pos)
        limit = int(4 * np.linalg.norm(self.mesh.extents) / self.step) + 1
        sliding = np.ones(len(rows), dtype=bool)
        for _ in range(limit):
            done = normal @ self.g >= self.cos_dl
            along = self.g - (normal @ self.g)[:, None] * normal
            stuck = ~done & (np.linalg.norm(along, axis=1) < 1e-3)
            t.alive[rows[stuck & sliding]] = False
            self.release(t, rows[done & sliding], pos[done & sliding])
            sliding &= ~done & ~stuck
            if not sliding.any():
                return
            k = np.flatnonzero(sliding)
            target = pos[k] + self.step * unit(along[k])
            back, below = self.cast(target, -normal[k])
            fell_off = back > self.step + self.lift
            on = ~fell_off
            new_normal = normal[k].copy()
            if on.any():
                new_normal[on] = self.facing(below[on], -normal[k][on])
            surface = target - np.where(fell_off, 0.0, back)[:, None] * normal[k]
            moved = np.where(on[:, None], surface + self.lift * new_normal, target)
            # The chord to the new point must not cut through the object: where it would,
            # the slide stops short of that wall and follows it next.
            chord = moved - pos[k]
            span = np.linalg.norm(chord, axis=1)
            reach, wall = self.cast(pos[k], unit(chord))
            cut = reach < span + self.eps
            if cut.any():
                moved[cut] = pos[k][cut] + np.maximum(reach[cut] - self.lift, 0.0)[:, None] * unit(chord[cut])
                new_normal[cut] = self.facing(wall[cut], chord[cut])
                fell_off &= ~cut
            # Water only runs downhill: a step that does not descend means it pools here.
            stalled = (moved - pos[k]) @ self.g < 0.05 * self.step
            t.alive[rows[k[stalled]]] = False
            sliding[k[stalled]] = False
            pos[k] = moved
            normal[k] = new_normal
            self.record(t, rows[k[~stalled]], pos[k[~stalled]])
            fell_off &= ~stalled
            self.release(t, rows[k[fell_off]], pos[k[fell_off]])
            sliding[k[fell_off]] = False
        t.alive[rows[sliding]] = False

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
        for r in rows:
            self.points.append([t.pos[r].copy()])
        return child


def grow_trajectories(mesh: trimesh.Trimesh, positions: np.ndarray, normals: np.ndarray,
                      water: np.ndarray, gravity, rng: np.random.Generator, *,
                      curve_angle: float, division_probability: float, roll_angle: float,
                      step_length: float, length_scale: float, max_branches: int,
                      drip_limit: float, caster=None) -> TrajectoryResult:
    """Stage 3: grow one icicle per drip point with the paper's L-system.

    ``w: FX;  p1': X -(1-d)-> +(c)FFF/(a)X;  p1'': X -(d)-> [(c)+(30)F-(30)FX]A;
    p2: A -> +(c)FFF/(a)X``, with roll ``a = au * 137.5 / 360``. The turtle starts at the
    drip point heading along gravity. Generations: ``round((kL * wc - F) / 3F)``, so the
    trunk is about ``kL * wc`` long. A step that would cross the object instead follows
    its surface along gravity until the drip criterion holds, then grows on from there.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object the icicles hang from, in meters.
    positions, normals : (k, 3) float
        Drip points on ``mesh`` and the outward normals of their faces, which lift each
        trajectory's start just off the surface (interpolated vertex normals can point
        into thin parts).
    water : (k,) float
        Water coefficient at each drip point, meters.
    gravity : (3,) float
    rng : numpy.random.Generator
    curve_angle, roll_angle : float
        c and au, degrees.
    division_probability : float
        d, in [0, 1].
    step_length : float
        Length of F, meters.
    length_scale : float
        Icicle meters per meter of water coefficient.
    max_branches : int
        Branches per icicle at most (d = 1 would otherwise double them every generation).
    drip_limit : float
        dl, degrees: where a collision slide may drip again.
    caster : callable, optional
        A `icefarm.geometry.ray_caster` of ``mesh`` to reuse (stage 1 may have built one).
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    water = np.asarray(water, dtype=np.float64).reshape(-1)
    if not len(positions) == len(normals) == len(water):
        raise ValueError("positions, normals and water need one row per drip point")
    if not 0 <= division_probability <= 1:
        raise ValueError(f"division_probability must lie in [0, 1], got {division_probability}")
    if step_length <= 0 or length_scale <= 0 or max_branches < 1:
        raise ValueError("step_length and length_scale must be positive, max_branches >= 1")
    n = len(positions)
    grower = _Grower(mesh, gravity, step_length, drip_limit, caster)
    g = grower.g
    generations = np.maximum(0, np.round((length_scale * water - step_length) / (3 * step_length))).astype(int)
    u, v = perpendicular_basis(g)
    spin = rng.uniform(0, 2 * np.pi, n)[:, None]
    turtles = _Turtles(
        pos=positions + grower.eps * unit(normals),
        heading=np.tile(g, (n, 1)),
        left=np.cos(spin) * u + np.sin(spin) * v,
        branch=np.arange(n),
        icicle=np.arange(n),
        pending_a=np.zeros(n, dtype=bool),
        alive=np.ones(n, dtype=bool),
    )
    grower.points = [[p.copy()] for p in turtles.pos]
    parents = [-1] * n
    branch_count = np.ones(n, dtype=int)
    roll = roll_angle * GOLDEN_ROLL / 360.0
    grower.forward(turtles, np.arange(n))  # the axiom's F
    for gen in range(int(generations.max(initial=0))):
        active = turtles.alive & (generations[turtles.icicle] > gen)
        draws = rng.random(len(turtles.alive))
        divide = active & ~turtles.pending_a & (draws < division_probability)
        for r in np.flatnonzero(divide):  # cap per icicle, in turtle order
            if branch_count[turtles.icicle[r]] >= max_branches:
                divide[r] = False
            else:
                branch_count[turtles.icicle[r]] += 1
        grow = np.flatnonzero(active & ~divide)
        turtles.pending_a[grow] = False
        grower.turn(turtles, grow, curve_angle)
        for _ in range(3):
            grower.forward(turtles, grow)
        grower.roll(turtles, grow, roll)
        split = np.flatnonzero(divide)
        if len(split):
            parents.extend(turtles.branch[split].tolist())
            child = grower.new_branches(turtles, split)
            turtles.pending_a[split] = True
            turtles = turtles.append(child)
            rows = np.arange(len(turtles.alive) - len(split), len(turtles.alive))
            grower.turn(turtles, rows, curve_angle + BRANCH_ANGLE)
            grower.forward(turtles, rows)
            grower.turn(turtles, rows, -BRANCH_ANGLE)
            grower.forward(turtles, rows)
    counts = np.array([len(p) for p in grower.points], dtype=np.int64)
    branch_icicle = np.empty(len(counts), dtype=np.int64)
    branch_icicle[turtles.branch] = turtles.icicle
    return TrajectoryResult(
        points=np.concatenate([np.array(p) for p in grower.points]) if counts.size else np.zeros((0, 3)),
        branch_offsets=np.r_[0, np.cumsum(counts)],
        branch_icicle=branch_icicle,
        branch_parent=np.array(parents, dtype=np.int64),
    )
