"""Stage 3 (paper 4.3): icicle trajectories from the L-system, with collisions (4.3.1).

Three departures from the literal rules, each where the literal turtle is unphysical: the
bend saturates at ``max_tilt`` from gravity (a steady ``+(c)`` with no roll winds the
turtle into a loop, and water does not flow up), a horizontal wind orients every bend
(a wind-blown icicle leans downwind), and a branch holds its 30 degrees until it is
``branch_spread`` aside (the paper's single F puts it 2 mm off: glass wool, not branches).
"""

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
    branch_cut : (b,) float or None
        Meters of each branch that something below took away (`icefarm.placement.
        stop_at_ground`): the icicle reached the ground and stopped lengthening, but its
        water kept thickening it as if it were that much longer. None: nothing was cut.
    """

    points: np.ndarray
    branch_offsets: np.ndarray
    branch_icicle: np.ndarray
    branch_parent: np.ndarray
    branch_cut: np.ndarray | None = None

    @property
    def n_branches(self) -> int:
        return len(self.branch_icicle)

    @property
    def cut(self) -> np.ndarray:
        """``(b,)`` meters cut from each branch (`branch_cut`, zeros when None)."""
        if self.branch_cut is None:
            return np.zeros(self.n_branches)
        return np.asarray(self.branch_cut, dtype=np.float64)

    def branch(self, i: int) -> np.ndarray:
        """``(k, 3)`` points of branch ``i``."""
        return self.points[self.branch_offsets[i]:self.branch_offsets[i + 1]]


@dataclass(frozen=True)
class TrajectoryStats:
    """What `measure_trajectories` reports about a `TrajectoryResult`.

    Attributes
    ----------
    upward_share : float
        Fraction of all segments (free growth and slides) that rise against gravity by
        more than `UPWARD_TOLERANCE` of their length; nan without segments.
    branch_spread_mm : float
        Median, over non-trunk branches, of the distance from the branch tip to its parent
        polyline, in millimeters; nan without branches.
    trunk_lengths : (i,) float
        Arc length of each trunk polyline (``branch_parent == -1``), meters.
    length_cv : float
        Coefficient of variation (std / mean) of ``trunk_lengths``; nan for fewer than 2.
    """

    upward_share: float
    branch_spread_mm: float
    trunk_lengths: np.ndarray
    length_cv: float


UPWARD_TOLERANCE = 1e-6  # of a segment's length: rounding, not a rise
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
    rest: np.ndarray       # (t,) int, generations a new branch waits: its spread used them

    def append(self, other: "_Turtles") -> "_Turtles":
        return _Turtles(*(np.concatenate([a, b]) for a, b in zip(vars(self).values(), vars(other).values())))

    def take(self, rows: np.ndarray) -> "_Turtles":
        return _Turtles(*(a[rows].copy() for a in vars(self).values()))


def _rotate(a: np.ndarray, b: np.ndarray, degrees) -> tuple[np.ndarray, np.ndarray]:
    """Rotate the orthonormal pair ``(a, b)`` (rows) by ``degrees`` in their plane."""
    t = np.radians(np.asarray(degrees, dtype=np.float64))[..., None]
    return a * np.cos(t) + b * np.sin(t), b * np.cos(t) - a * np.sin(t)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products ``(k,)`` of ``(k, 3)`` arrays."""
    return np.einsum("ij,ij->i", a, b)


def _across(v: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Unit part ``(k, 3)`` of ``v`` perpendicular to the unit rows ``h`` (any perpendicular if none)."""
    out = v - _dot(v, h)[:, None] * h
    bad = np.linalg.norm(out, axis=1) < 1e-9
    if bad.any():
        out[bad] = [perpendicular_basis(x)[0] for x in h[bad]]
    return unit(out)


class _Grower:
    """Runs the turtles of one trajectory stage against one mesh (collisions, slides)."""

    def __init__(self, mesh, gravity, step, drip_limit, caster=None, max_tilt=90.0, wind=None):
        self.mesh, self.g, self.step = mesh, unit(gravity), step
        self.cos_dl = np.cos(np.radians(drip_limit))
        self.max_tilt = np.radians(max_tilt)
        self.wind = wind  # (3,) unit, perpendicular to gravity, or None for still air
        self.eps = 1e-4 * float(np.linalg.norm(mesh.extents))
        # Slide points float this far off the surface so chords between them stay outside
        # curved parts (sagitta of a step on a 2 mm radius); the ice covers the gap.
        self.lift = max(self.eps, 0.25 * step)
        self.points: list[list[np.ndarray]] = []
        self.caster = caster or ray_caster(mesh)

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
            towards = np.where((np.linalg.norm(across, axis=1) > 1e-9)[:, None], unit(across), left)
            new_h, new_t = _rotate(h, towards, degrees)
            # L's share of the turning plane turns with it (a rotation, so L stays unit and normal to H)
            new_l = left + _dot(left, towards)[:, None] * (new_t - towards)
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
            side = np.where((np.linalg.norm(side, axis=1) > 1e-9)[:, None], side, fallback)
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
        """``F`` for the turtles ``rows``: one step, or a slide along the object on collision.

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
            self.slide(t, rows[blocked], hits, face[blocked])
        return rows[blocked]

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
        child.rest[:] = 0
        for r in rows:
            self.points.append([t.pos[r].copy()])
        return child


def spread_steps(branch_spread: float, step_length: float) -> int:
    """F steps a branch holds its 30 degrees to lie ``branch_spread`` aside (1: the paper)."""
    aside = step_length * np.sin(np.radians(BRANCH_ANGLE))
    return max(1, int(np.ceil(branch_spread / aside - 1e-9)))


def grow_trajectories(mesh: trimesh.Trimesh, positions: np.ndarray, normals: np.ndarray,
                      water: np.ndarray, gravity, rng: np.random.Generator, *,
                      curve_angle: float, division_probability: float, roll_angle: float,
                      step_length: float, length_scale: float, max_branches: int,
                      drip_limit: float, max_tilt: float = 60.0, wind=(0.0, 0.0, 0.0),
                      branch_spread: float = 0.02, caster=None) -> TrajectoryResult:
    """Stage 3: grow one icicle per drip point with the paper's L-system.

    ``w: FX;  p1': X -(1-d)-> +(c)FFF/(a)X;  p1'': X -(d)-> [(c)+(30)F-(30)FX]A;
    p2: A -> +(c)FFF/(a)X``, with roll ``a = au * 137.5 / 360``. The turtle starts at the
    drip point heading along gravity. Generations: ``round((kL * wc - F) / 3F)``, so the
    trunk is about ``kL * wc`` long. A step that would cross the object instead follows
    its surface along gravity until the drip criterion holds, then grows on from there.

    Departures from the literal rules: each ``+(c)`` adds only ``1 - tilt / max_tilt`` of
    its tilt, so icicles bend towards max_tilt and never up; with wind it turns towards
    the wind instead of L; p1'' repeats its first F ``n = ceil(branch_spread / (F sin 30))``
    times (at most ``1 + 3`` per generation the icicle has left), and the branch then rests
    ``round((n - 1) / 3)`` generations so that it is no longer than the paper's.

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
    max_tilt : float
        Degrees in [0, 90]: no heading leans further than this from gravity.
    wind : (3,) float
        Direction the wind blows; only its part perpendicular to gravity counts, and zero
        (still air) leaves each icicle's bend to its random initial spin and the roll.
    branch_spread : float
        Meters a new branch moves aside from its parent before it grows on parallel; 0
        keeps the paper's single F (``F sin 30`` aside).
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
    if not 0 <= max_tilt <= 90:
        raise ValueError(f"max_tilt must lie in [0, 90] degrees, got {max_tilt}")
    if branch_spread < 0:
        raise ValueError(f"branch_spread must be >= 0, got {branch_spread}")
    n = len(positions)
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    wind = np.asarray(wind, dtype=np.float64).reshape(3)
    wind = wind - (wind @ g) * g
    blowing = bool(np.linalg.norm(wind) > 1e-9)
    grower = _Grower(mesh, g, step_length, drip_limit, caster, max_tilt, unit(wind) if blowing else None)
    generations = np.maximum(0, np.round((length_scale * water - step_length) / (3 * step_length))).astype(int)
    u, v = perpendicular_basis(g)
    spin = rng.uniform(0, 2 * np.pi, n)[:, None]  # drawn in wind too: the same seed, the same branches
    turtles = _Turtles(
        pos=positions + grower.eps * unit(normals),
        heading=np.tile(g, (n, 1)),
        left=np.tile(grower.wind, (n, 1)) if blowing else np.cos(spin) * u + np.sin(spin) * v,
        branch=np.arange(n),
        icicle=np.arange(n),
        pending_a=np.zeros(n, dtype=bool),
        alive=np.ones(n, dtype=bool),
        rest=np.zeros(n, dtype=np.int64),
    )
    grower.points = [[p.copy()] for p in turtles.pos]
    parents = [-1] * n
    branch_count = np.ones(n, dtype=int)
    roll = roll_angle * GOLDEN_ROLL / 360.0
    n_spread = spread_steps(branch_spread, step_length)
    grower.forward(turtles, np.arange(n))  # the axiom's F
    for gen in range(int(generations.max(initial=0))):
        active = turtles.alive & (generations[turtles.icicle] > gen)
        draws = rng.random(len(turtles.alive))
        resting = active & (turtles.rest > 0)
        turtles.rest[resting] -= 1
        active &= ~resting
        divide = active & ~turtles.pending_a & (draws < division_probability)
        for r in np.flatnonzero(divide):  # cap per icicle, in turtle order
            if branch_count[turtles.icicle[r]] >= max_branches:
                divide[r] = False
            else:
                branch_count[turtles.icicle[r]] += 1
        grow = np.flatnonzero(active & ~divide)
        turtles.pending_a[grow] = False
        grower.bend(turtles, grow, curve_angle)
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
            grower.bend(turtles, rows, curve_angle)
            parallel, parallel_left = grower.depart(turtles, rows)
            # [+(30) F^n -(30) F X]: the spread may not outgrow the generations left, so a
            # late branch stays a short spur instead of hanging below the whole icicle
            left_gens = generations[turtles.icicle[rows]] - gen - 1
            steps = np.clip(1 + 3 * left_gens, 1, n_spread)
            spreading = np.ones(len(rows), dtype=bool)
            for k in range(int(steps.max())):
                hit = grower.forward(turtles, rows[spreading & (steps > k)])
                spreading &= ~np.isin(rows, hit)  # a collision's slide already set its course
            turtles.heading[rows[spreading]] = parallel[spreading]
            turtles.left[rows[spreading]] = parallel_left[spreading]
            turtles.rest[rows] = np.rint((steps - 1) / 3).astype(np.int64)
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


def measure_trajectories(traj: TrajectoryResult, gravity) -> TrajectoryStats:
    """Shape statistics of trajectories: rising segments, branch spread, trunk lengths.

    Parameters
    ----------
    traj : TrajectoryResult
        Polylines in meters.
    gravity : (3,) float
        Direction of gravity (normalised here).

    Returns
    -------
    TrajectoryStats
    """
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    pts, offsets, parent = traj.points, np.asarray(traj.branch_offsets), np.asarray(traj.branch_parent)
    nb = traj.n_branches
    owner = np.repeat(np.arange(nb), np.diff(offsets))  # (p,) branch of each point
    joins = np.flatnonzero(owner[1:] == owner[:-1])     # segment j runs from point j to j + 1
    seg_a, seg = pts[joins], pts[joins + 1] - pts[joins]
    length = np.linalg.norm(seg, axis=1)
    real = length > 0
    rising = seg[real] @ g < -UPWARD_TOLERANCE * length[real]
    upward_share = float(rising.mean()) if real.any() else float("nan")

    seg_branch = owner[joins]
    per_branch = np.bincount(seg_branch, weights=length, minlength=nb)
    trunk_lengths = per_branch[parent == -1]
    mean = trunk_lengths.mean() if len(trunk_lengths) else 0.0
    length_cv = float(trunk_lengths.std() / mean) if len(trunk_lengths) >= 2 and mean > 0 else float("nan")

    npts = np.diff(offsets)
    # Branches cut away whole (an icicle stopped by the ground) have no points: skip them.
    children = np.flatnonzero((parent >= 0) & (npts > 0))
    children = children[npts[parent[children]] > 0]
    if len(children) == 0:
        return TrajectoryStats(upward_share, float("nan"), trunk_lengths, length_cv)
    seg_count = np.bincount(seg_branch, minlength=nb)
    seg_start = np.r_[0, np.cumsum(seg_count)][:-1]  # segments are stored branch after branch
    tips = pts[offsets[children + 1] - 1]
    # a parent of one point (it ended at once) is a zero-length segment on that point
    one = seg_count[parent[children]] == 0
    dist = np.full(len(children), np.inf)
    dist[one] = np.linalg.norm(tips[one] - pts[offsets[parent[children[one]]]], axis=1)
    todo = np.flatnonzero(~one)
    counts = seg_count[parent[children[todo]]]
    # tip-to-segment distances in chunks of about a million pairs, for memory
    bounds = np.searchsorted(np.cumsum(counts), np.arange(1, counts.sum() // 1_000_000 + 1) * 1_000_000)
    for part in np.split(np.arange(len(todo)), np.unique(bounds)):
        if len(part) == 0:
            continue
        c = counts[part]
        pair = np.repeat(np.arange(len(part)), c)
        within = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
        s = seg_start[parent[children[todo[part]]]][pair] + within
        a, ab, tip = seg_a[s], seg[s], tips[todo[part]][pair]
        f = np.clip(np.divide(_dot(tip - a, ab), _dot(ab, ab), out=np.zeros(len(s)), where=length[s] > 0), 0.0, 1.0)
        d = np.linalg.norm(a + f[:, None] * ab - tip, axis=1)
        best = np.full(len(part), np.inf)
        np.minimum.at(best, pair, d)
        dist[todo[part]] = best
    return TrajectoryStats(upward_share, float(np.median(dist) * 1000.0), trunk_lengths, length_cv)
