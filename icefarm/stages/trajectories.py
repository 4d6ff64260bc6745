"""Stage 3 (paper 4.3): icicle trajectories from the L-system, with collisions (4.3.1).

Three departures from the literal rules, each where the literal turtle is unphysical: the
bend saturates at ``max_tilt`` from gravity (a steady ``+(c)`` with no roll winds the
turtle into a loop, and water does not flow up), a horizontal wind orients every bend
(a wind-blown icicle leans downwind), and a branch holds its 30 degrees until it is
``branch_spread`` aside (the paper's single F puts it 2 mm off: glass wool, not branches),
or for a third of what it grows when born late (a side tip, not a splayed finger).

The turtle that draws them, with its collisions, is `turtles`; their shape statistics
(rising segments, branch spread, trunk lengths) are `trajectory_stats`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from ..geometry import perpendicular_basis, unit
from ..params import TrajectoriesParams
from ..tol import tol
from .turtles import BRANCH_ANGLE, _Grower, _Turtles


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
    branch_growth : (b,) float or None
        Growth ratio of each branch's profile (base radius added per meter of length) under
        a physical storm, whose short icicles thicken as much as long ones (its icicle's,
        `icefarm.stages.icicle_size.growth_ratios`). None: ``surface.growth_ratio`` for all.
    """

    points: np.ndarray
    branch_offsets: np.ndarray
    branch_icicle: np.ndarray
    branch_parent: np.ndarray
    branch_cut: np.ndarray | None = None
    branch_growth: np.ndarray | None = None

    @property
    def n_branches(self) -> int:
        return len(self.branch_icicle)

    @property
    def cut(self) -> np.ndarray:
        """``(b,)`` meters cut from each branch (`branch_cut`, zeros when None)."""
        if self.branch_cut is None:
            return np.zeros(self.n_branches)
        return np.asarray(self.branch_cut, dtype=np.float64)

    def growth(self, default: float) -> np.ndarray:
        """``(b,)`` growth ratio of each branch (`branch_growth`, ``default`` when None)."""
        if self.branch_growth is None:
            return np.full(self.n_branches, float(default))
        return np.asarray(self.branch_growth, dtype=np.float64)

    def branch(self, i: int) -> np.ndarray:
        """``(k, 3)`` points of branch ``i``."""
        return self.points[self.branch_offsets[i]:self.branch_offsets[i + 1]]


GOLDEN_ROLL = 137.5  # degrees: the plant-like spiral of the paper's roll (a = au * 137.5 / 360)


def spread_steps(branch_spread: float, step_length: float) -> int:
    """F steps a branch holds its 30 degrees to lie ``branch_spread`` aside (1: the paper)."""
    aside = step_length * np.sin(np.radians(BRANCH_ANGLE))
    return max(1, int(np.ceil(branch_spread / aside - tol.slack)))


@dataclass(frozen=True)
class TrajectoryOptions:
    """How stage 3 grows the icicles: the ``trajectories`` parameter group with what it reads
    from elsewhere (gravity, ``drips.drip_limit``, a physical storm's branch life).

    Attributes
    ----------
    gravity : (3,) float
        Direction of gravity.
    drip_limit : float
        dl, degrees: where a collision slide may drip again.
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
    max_tilt : float
        Degrees in [0, 90]: no heading leans further than this from gravity.
    wind : (3,) float
        Direction the wind blows; only its part perpendicular to gravity counts, and zero
        (still air) leaves each icicle's bend to its random initial spin and the roll.
    branch_spread : float
        Meters a new branch moves aside from its parent before it grows on parallel; 0
        keeps the paper's single F (``F sin 30`` aside).
    contact : {"slide", "stop"}
        Where a step meets the object: the paper's slide, or the branch ends on the surface.
    branch_life : float
        In ]0, 1]: a branch grows for this share of the generations its icicle has left when
        it splits off (1: the paper's, to the icicle's last generation, so that every branch
        ends beside the trunk's tip; a physical storm's `BRANCH_LIFE`).
    """

    gravity: Any
    drip_limit: float
    curve_angle: float
    division_probability: float
    roll_angle: float
    step_length: float
    length_scale: float
    max_branches: int
    max_tilt: float = 60.0
    wind: Any = (0.0, 0.0, 0.0)
    branch_spread: float = 0.02
    contact: str = "slide"
    branch_life: float = 1.0


def trajectory_options(group: TrajectoriesParams, gravity, drip_limit: float,
                       branch_life: float = 1.0) -> TrajectoryOptions:
    """The `TrajectoryOptions` of a job's ``trajectories`` parameter group."""
    return TrajectoryOptions(gravity=gravity, drip_limit=drip_limit, branch_life=branch_life,
                             **dataclasses.asdict(group))


def grow_trajectories(mesh: trimesh.Trimesh, positions: np.ndarray, normals: np.ndarray,
                      water: np.ndarray, rng: np.random.Generator, options: TrajectoryOptions, *,
                      caster=None) -> TrajectoryResult:
    """Stage 3: grow one icicle per drip point with the paper's L-system.

    ``w: FX;  p1': X -(1-d)-> +(c)FFF/(a)X;  p1'': X -(d)-> [(c)+(30)F-(30)FX]A;
    p2: A -> +(c)FFF/(a)X``, with roll ``a = au * 137.5 / 360``. The turtle starts at the
    drip point heading along gravity. Generations: ``round((kL * wc - F) / 3F)``, so the
    trunk is about ``kL * wc`` long. A step that would cross the object instead follows
    its surface along gravity until the drip criterion holds, then grows on from there
    (``contact="slide"``), or ends there (``"stop"``).

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
    rng : numpy.random.Generator
    options : TrajectoryOptions
        The L-system's angles, steps and limits, and gravity.
    caster : callable, optional
        A `icefarm.spatial.ray_caster` of ``mesh`` to reuse (stage 1 may have built one).
    """
    o = options
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    water = np.asarray(water, dtype=np.float64).reshape(-1)
    if not len(positions) == len(normals) == len(water):
        raise ValueError("positions, normals and water need one row per drip point")
    if not 0 < o.branch_life <= 1:  # not a parameter, so the registry does not check it
        raise ValueError(f"branch_life must lie in ]0, 1], got {o.branch_life}")
    grower, turtles, generations = _start(mesh, positions, normals, water, rng, o, caster)
    parents = [-1] * len(positions)
    branch_count = np.ones(len(positions), dtype=int)
    roll = o.roll_angle * GOLDEN_ROLL / 360.0
    n_spread = spread_steps(o.branch_spread, o.step_length)
    for gen in range(int(generations.max(initial=0))):
        active = turtles.alive & (turtles.last > gen)
        draws = rng.random(len(turtles.alive))
        resting = active & (turtles.rest > 0)
        turtles.rest[resting] -= 1
        active &= ~resting
        divide = active & ~turtles.pending_a & (draws < o.division_probability)
        for r in np.flatnonzero(divide):  # cap per icicle, in turtle order
            if branch_count[turtles.icicle[r]] >= o.max_branches:
                divide[r] = False
            else:
                branch_count[turtles.icicle[r]] += 1
        grow = np.flatnonzero(active & ~divide)
        turtles.pending_a[grow] = False
        grower.bend(turtles, grow, o.curve_angle)
        for _ in range(3):
            grower.forward(turtles, grow)
        grower.roll(turtles, grow, roll)
        split = np.flatnonzero(divide)
        if len(split):
            parents.extend(turtles.branch[split].tolist())
            turtles = _branch(grower, turtles, split, generations, gen, o, n_spread)
    counts = np.array([len(p) for p in grower.points], dtype=np.int64)
    branch_icicle = np.empty(len(counts), dtype=np.int64)
    branch_icicle[turtles.branch] = turtles.icicle
    return TrajectoryResult(
        points=np.concatenate([np.array(p).reshape(-1, 3) for p in grower.points]) if counts.size else np.zeros((0, 3)),
        branch_offsets=np.r_[0, np.cumsum(counts)],
        branch_icicle=branch_icicle,
        branch_parent=np.array(parents, dtype=np.int64),
    )


def _start(mesh, positions, normals, water, rng, o: TrajectoryOptions, caster):
    """The grower, one turtle per drip point just off the surface heading along gravity
    after the axiom's F, and each icicle's generations ``(k,) int``."""
    n = len(positions)
    g = unit(np.asarray(o.gravity, dtype=np.float64).reshape(3))
    wind = np.asarray(o.wind, dtype=np.float64).reshape(3)
    wind = wind - (wind @ g) * g
    blowing = bool(np.linalg.norm(wind) > tol.zero)
    grower = _Grower(mesh, g, o.step_length, o.drip_limit, caster, o.max_tilt, unit(wind) if blowing else None,
                     slide=o.contact == "slide")
    generations = np.maximum(0, np.round((o.length_scale * water - o.step_length) / (3 * o.step_length))).astype(int)
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
        last=generations.astype(np.int64),
    )
    grower.points = [[p.copy()] for p in turtles.pos]
    met = grower.forward(turtles, np.arange(n))  # the axiom's F
    if o.contact == "stop":  # the drop falls straight onto the object: no icicle (an empty branch)
        for r in met:
            grower.points[r] = []
    return grower, turtles, generations


def _branch(grower, turtles, split, generations, gen: int, o: TrajectoryOptions, n_spread: int):
    """p1'' on the turtles ``split``: each starts a branch ``[+(30) F^n -(30) F X]``; returns
    the turtles with the new branches appended."""
    child = grower.new_branches(turtles, split)
    turtles.pending_a[split] = True
    turtles = turtles.append(child)
    rows = np.arange(len(turtles.alive) - len(split), len(turtles.alive))
    grower.bend(turtles, rows, o.curve_angle)
    parallel, parallel_left = grower.depart(turtles, rows)
    # [+(30) F^n -(30) F X]: the spread may not outgrow a third of the generations
    # left, so a late branch is a short side tip hanging beside its parent's (as on
    # real icicles) instead of a finger splayed at 30 degrees to its end: three or
    # four of those make the fence's and the eaves' tips into claws
    left_gens = np.ceil(o.branch_life * (generations[turtles.icicle[rows]] - gen - 1)).astype(np.int64)
    turtles.last[rows] = gen + 1 + left_gens
    steps = np.clip(1 + left_gens, 1, n_spread)
    spreading = np.ones(len(rows), dtype=bool)
    for k in range(int(steps.max())):
        hit = grower.forward(turtles, rows[spreading & (steps > k)])
        spreading &= ~np.isin(rows, hit)  # a collision's slide already set its course
    turtles.heading[rows[spreading]] = parallel[spreading]
    turtles.left[rows[spreading]] = parallel_left[spreading]
    turtles.rest[rows] = np.rint((steps - 1) / 3).astype(np.int64)
    grower.forward(turtles, rows)
    return turtles
