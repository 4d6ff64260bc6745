"""Stage 4 (paper 4.4): the ice surface, icicles, their bases and glaze ice as one watertight mesh.

Every icicle branch becomes a chain of metaballs whose radii follow the profile of
Equation 1; metaballs around each drip point form the base (Equation 2) and metaballs
over the wet surface form the glaze (Equation 3). The icicle and base balls add into ONE
field, so branches fuse with their trunk and touching icicles fuse with each other, and
the iso-surface of that field is polygonised by marching cubes into one mesh in meters.
The glaze covers the whole wet surface, so at the voxel the tip radius needs it would
dominate the mesh: its balls get a field of their own on the coarser ``glaze.voxel_size``
lattice, and the two closed surfaces are joined by a boolean union (manifold3d), run only
where they come close (`fuse_fields`). With ``glaze.voxel_size <= surface.voxel_size``
the glaze joins the one field instead, and fuses smoothly with the bases.

The metaballs are Gaussian (Blinn's blobby model): the one kernel that is both radial
and separable. Separability turns the field of a block of ``B^3`` samples into a matrix
product over the balls touching that block, so evaluation runs in BLAS, and only in the
blocks that balls reach (a sparse block grid: memory and time follow the ice, not its
bounding box). Each sample is computed once, by the block that owns it; a block marches
its cells with its upper neighbours' first samples as a halo, so blocks can never
disagree on a shared sample and the mesh closes across seams. Calibration (module
constants below):

* chain of balls of radius R: width ``s = KAPPA * R``, spacing ``SPACING * s``; the
  line integral ``(sqrt(pi) s / h) exp(-rho^2 / s^2)`` of a dense chain equals
  ``LEVEL`` at ``rho = R`` exactly, so a straight chain's surface sits at R
  (bumps between balls stay below 0.1 % of R); the last ball of a branch weighs
  ``TIP_WEIGHT`` so the end of the chain is a hemisphere of radius R(L) (within 2 %);
* base and glaze balls of radius r, one per area A of the surface: width
  ``max(SHEET_KAPPA * r, SHEET_OVERLAP * sqrt(A))`` and a weight that makes the sheet
  they form r thick on each side of the surface (a plane of balls integrates to
  ``pi s^2 / A exp(-z^2 / s^2)``), so Equations 2 and 3 give ice thickness.

``surface.mode == "tubes"`` (the paper's future work, 6.1) sweeps each branch as a
closed tube with the same profile instead: instant, no fusion, no base, no glaze.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from ..errors import InputError
from .drips import DripResult
from .trajectories import TrajectoryResult
from .water import WaterResult

# Chain calibration (see the module docstring): width/radius, spacing/width, tip weight.
KAPPA = 0.6
SPACING = 1.2
TIP_WEIGHT = 1.4
# Iso level of the field: a dense straight chain of unit-weight balls crosses it at R.
LEVEL = math.sqrt(math.pi) / SPACING * math.exp(-1.0 / KAPPA**2)
# Width/thickness of base and glaze balls, and their least width per ball spacing
# (sqrt of the area per ball): about pi * 2^2 = 12 balls overlap at each point of a sheet.
SHEET_KAPPA = 1.0
SHEET_OVERLAP = 2.0
# With the glaze on its own coarser lattice, its sheet is at least this many glaze voxels
# thick (the extra thickness goes inside the object), so marching cubes tears it less.
COAT_SHEET = 2.0
# Each ball is cut off where its field falls below this fraction of LEVEL.
CUTOFF = 1e-3
# Samples (and cells) per block edge.
BLOCK = 16
# Ripples and noise fade out over this many tip radii above the tip, so the drop
# at the tip keeps the tip radius (Maeno's 2.44 mm) whatever the ripple phase.
TIP_CALM = 2.0
# Marching cubes runs on field**_POWER (see polygonize).
_POWER = KAPPA**2 / 2
# Field samples closer than this (relative) to the level are pushed off it, so no
# marching-cubes vertex lands on a grid corner (which would make zero-area faces).
_NUDGE = 1e-3
# Most balls in one matrix product (see _block_fields).
_SEGMENT = 64
# Floats in one stacked product of block fields (small enough to stay in a core's L2
# cache: 4x faster than 4M here) and in one batch of halo blocks for marching cubes.
_FIELD_BATCH = 500_000
_MARCH_BATCH = 4_000_000
# Fusion of two lattices (`fuse_fields`): most tiles in the dense grid of a region.
_MAX_TILES = 2**22
# Refuse voxel sizes whose field (float32 over the blocks the balls reach) needs more,
# or that pair balls with more blocks than this (about 100 bytes each on the way).
_MAX_FIELD_BYTES = 2 * 2**30
_MAX_PAIRS = 10_000_000


@dataclass(frozen=True)
class IceResult:
    """The ice: icicles, bases and glaze fused into one mesh, with measured plausibility.

    Attributes
    ----------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound triangles; watertight in metaball mode, one closed tube per
        branch in tubes mode.
    tip_radius_mm : float
        Distance from each trunk's tip point to the ice surface ahead of it (median over
        the drop's mesh vertices), median over icicles, in millimeters; nan without icicles.
    length_to_diameter : (i,) float64
        Per icicle trunk (in branch order): trunk length over the base diameter measured on
        the mesh (a line fitted to the trunk's radius along its length, taken at x = 0).
        Real icicles: 8 to 32. NaN where a trunk cannot be measured: too short for four
        radius samples between 30 % and 90 % of its length (under 5 mm), or a fitted base
        radius that is not positive. Entries stay aligned with the trunks, so consumers
        drop the NaN themselves (the CLI's summary does).
    ripple_wavelength_cm : float
        Dominant period of the trunks' radius along their length, measured on the mesh,
        in centimeters (real icicles: about 1 cm); nan when ``ripple_amplitude`` is 0 or
        no trunk is long enough to show two ripples.
    balls : int
        Metaballs in the fields: icicles, bases and glaze (0 in tubes mode).
    """

    vertices: np.ndarray
    faces: np.ndarray
    tip_radius_mm: float
    length_to_diameter: np.ndarray
    ripple_wavelength_cm: float
    balls: int


@dataclass(frozen=True)
class Balls:
    """Gaussian metaballs ``weight * exp(-|p - center|^2 / width^2)``.

    Attributes
    ----------
    centers : (n, 3) float64
        In meters.
    widths : (n,) float64
        Gaussian width ``s``, in meters.
    weights : (n,) float64
        Peak value of each ball.
    """

    centers: np.ndarray
    widths: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return len(self.widths)


def concat_balls(*parts: Balls) -> Balls:
    """All balls of ``parts`` in one `Balls`."""
    return Balls(
        np.concatenate([p.centers for p in parts]).reshape(-1, 3),
        np.concatenate([p.widths for p in parts]),
        np.concatenate([p.weights for p in parts]),
    )


_NO_BALLS = Balls(np.zeros((0, 3)), np.zeros(0), np.zeros(0))


# --------------------------------------------------------------------------- profile


def profile_radius(x, length, tip, growth, amplitude, frequency, min_radius=None):
    """Equation 1: icicle radius along its trajectory, in meters.

    ``R(x) = tip + (L - x) t + as sin(x fs)``, with the ripple fading to nothing over the
    last ``TIP_CALM`` tip radii so the tip keeps its radius.

    Parameters
    ----------
    x : (k,) float
        Arc length from the branch base (0) towards its tip, in meters.
    length : float or (k,) float
        Branch length L, in meters.
    tip, growth, amplitude, frequency : float
        ``tip`` (m), ``t`` (m/m), ``as`` (m), ``fs`` (rad/m).
    min_radius : float, optional
        Floor for the radius (ripples deeper than the icicle); default ``tip / 4``.

    Returns
    -------
    (k,) float
        Radius in meters.
    """
    x = np.asarray(x, dtype=np.float64)
    remaining = np.maximum(np.asarray(length, dtype=np.float64) - x, 0.0)
    calm = np.clip(remaining / (TIP_CALM * tip), 0.0, 1.0)
    r = tip + remaining * growth + amplitude * np.sin(x * frequency) * calm
    return np.maximum(r, tip / 4 if min_radius is None else min_radius)


def _branch_lengths(traj: TrajectoryResult):
    """Per point: arc length from its branch base; per branch: total length (meters)."""
    pts = np.asarray(traj.points, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    seg = np.zeros(len(pts))
    if len(pts) > 1:
        seg[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    seg[off[:-1][off[:-1] < len(pts)]] = 0.0  # no segment across a branch start
    cum = np.cumsum(seg)
    start = np.repeat(cum[off[:-1]] if len(pts) else np.zeros(0), np.diff(off))
    x = cum - start
    lengths = np.zeros(len(off) - 1)
    nonempty = np.diff(off) > 0
    lengths[nonempty] = x[off[1:][nonempty] - 1]
    return x, lengths


# --------------------------------------------------------------------------- balls


def icicle_balls(traj: TrajectoryResult, surface: dict, rng: np.random.Generator) -> Balls:
    """Metaball chains along every branch (paper 4.4.1-4.4.2).

    Balls are spaced ``SPACING * KAPPA * R(x)`` apart along each branch, from its base
    (x = 0) to exactly its tip (x = L); each is moved at random within ``noise`` in the
    plane perpendicular to the branch (uniform over the disk), except near the tip.

    Returns
    -------
    Balls
    """
    tip = surface["tip_radius"]
    prof = (tip, surface["growth_ratio"], surface["ripple_amplitude"], surface["ripple_frequency"])
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if len(branches) == 0:
        return _NO_BALLS
    x_pt, all_lengths = _branch_lengths(traj)
    lengths = all_lengths[branches]
    nb = len(branches)

    # Fine samples of each branch to integrate u(x) = int dx / h(x): balls sit at equal steps of u.
    step_min = SPACING * KAPPA * tip / 4
    if prof[2] > 0 and prof[3] > 0:
        step_min = min(step_min, 2 * math.pi / prof[3] / 16)
    nfine = np.maximum(np.ceil(lengths / step_min).astype(np.int64), 1) + 1
    fb = np.repeat(np.arange(nb), nfine)
    fstart = np.cumsum(nfine) - nfine
    fj = np.arange(nfine.sum()) - np.repeat(fstart, nfine)
    fx = fj * (lengths / (nfine - 1))[fb]
    fr = profile_radius(fx, lengths[fb], *prof)
    inv_h = 1.0 / (SPACING * KAPPA * fr)
    du = np.zeros_like(fx)
    du[1:] = 0.5 * (inv_h[1:] + inv_h[:-1]) * np.diff(fx)
    du[fstart] = 0.0
    u = np.cumsum(du)
    u_len = u[fstart + nfine - 1] - u[fstart]
    nint = np.ceil(u_len - 1e-9).astype(np.int64)  # intervals between balls; 0: one lone ball
    nballs = nint + 1
    bb = np.repeat(np.arange(nb), nballs)
    bk = np.arange(nballs.sum()) - np.repeat(np.cumsum(nballs) - nballs, nballs)
    # Global monotone u with a gap of 1 between branches, so np.interp never mixes branches.
    gap = np.arange(nb, dtype=np.float64)
    ug = u + gap[fb]
    target = (u[fstart] + gap)[bb] + bk * np.where(nint > 0, u_len / np.maximum(nint, 1), 0.0)[bb]
    bx = np.interp(target, ug, fx)
    bx[bk == nint[bb]] = lengths[bb][bk == nint[bb]]  # the last ball exactly at the tip
    radius = profile_radius(bx, lengths[bb], *prof)

    pos, tangent = _points_along(traj, x_pt, all_lengths, branches[bb], bx)

    noise = surface["noise"]
    if noise > 0:
        e1, e2 = _perpendicular_frame(tangent)
        calm = np.clip((lengths[bb] - bx) / (TIP_CALM * tip), 0.0, 1.0)
        rad = noise * np.sqrt(rng.random(len(bx))) * calm
        ang = rng.random(len(bx)) * (2 * math.pi)
        pos = pos + rad[:, None] * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)

    # Weights: a chain packed tighter than SPACING weighs proportionally less; the tip
    # ball weighs TIP_WEIGHT more to round the end; a lone ball is a sphere of radius R.
    weight = np.where(nint > 0, u_len / np.maximum(nint, 1), 1.0)[bb]
    weight = np.where(bk == nint[bb], weight * TIP_WEIGHT, weight)
    lone = (nint == 0)[bb]
    weight[lone] = LEVEL * math.exp(1.0 / KAPPA**2)
    return Balls(pos, KAPPA * radius, weight)


def _perpendicular_frame(tangent: np.ndarray):
    """Two unit vectors perpendicular to each unit ``tangent`` (k, 3) and to each other."""
    helper = np.where(np.abs(tangent[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(tangent, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(tangent, e1)


def sheet_balls(centers: np.ndarray, thickness: np.ndarray, area_per_ball: np.ndarray | float) -> Balls:
    """Balls on a surface that together make a sheet ``thickness`` thick on each side.

    A plane of Gaussian balls of width s and weight w, one per area A, has the field
    ``w pi s^2 / A exp(-z^2 / s^2)`` at height z: the weight puts ``LEVEL`` at
    ``z = thickness``. The width is ``SHEET_KAPPA * thickness`` but at least
    ``SHEET_OVERLAP * sqrt(A)``, so each point of the surface sees about a dozen balls and
    the sheet stays continuous, down to nothing where the thickness goes to zero.

    Parameters
    ----------
    centers : (k, 3) float
        On the surface, in meters.
    thickness : (k,) float
        Ice thickness over the surface at each ball (Equation 2's rb, Equation 3's rgi), in
        meters.
    area_per_ball : float or (k,) float
        Surface area per ball where they lie, in square meters.
    """
    thickness = np.maximum(np.asarray(thickness, dtype=np.float64), 0.0)
    area = np.broadcast_to(np.asarray(area_per_ball, dtype=np.float64), thickness.shape)
    width = np.maximum(SHEET_KAPPA * thickness, SHEET_OVERLAP * np.sqrt(area))
    weight = LEVEL * area / (math.pi * width**2) * np.exp((thickness / np.maximum(width, 1e-300)) ** 2)
    return Balls(np.asarray(centers, dtype=np.float64).reshape(-1, 3), width, weight)


def base_balls(object_mesh: trimesh.Trimesh, drips: DripResult, surface: dict,
               rng: np.random.Generator) -> Balls:
    """``nmb`` balls on the object around each drip point (paper 4.4.3, Equation 2).

    Points are drawn area-weighted on the faces that come within ``eb`` (Euclidean) of the
    drip point and connect to the drip point's face through such faces (so no ice jumps
    to a nearby but separate part); each ball makes the ice ``rb = (eb - d)^2 / eb^2 *
    wc * kb`` thick there (d: distance to the drip point, wc: its water coefficient).
    """
    eb, nmb, kb = surface["base_extent"], surface["base_balls"], surface["base_scale"]
    k = len(drips.positions)
    if k == 0 or eb <= 0 or nmb == 0 or kb <= 0:
        return _NO_BALLS
    tris = object_mesh.triangles
    centroids = tris.mean(axis=1)
    reach = np.linalg.norm(tris - centroids[:, None, :], axis=2).max(axis=1)
    pos = np.asarray(drips.positions, dtype=np.float64)
    near = cKDTree(centroids).query_ball_point(pos, eb + reach.max())
    drip = np.repeat(np.arange(k), [len(n) for n in near])
    face = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    close = np.linalg.norm(centroids[face] - pos[drip], axis=1) - reach[face] <= eb
    drip, face = drip[close], face[close]
    drip, face = _grow_from_drips(drip, face, np.asarray(drips.faces, dtype=np.int64), object_mesh)
    if len(face) == 0:
        return _NO_BALLS

    # Oversample each drip's faces by area, keep the points within eb, take nmb of them.
    areas = object_mesh.area_faces[face]
    cum = np.cumsum(areas)
    first = np.searchsorted(drip, np.arange(k))
    last = np.searchsorted(drip, np.arange(k), side="right")
    has = last > first
    total = np.where(has, cum[np.maximum(last - 1, 0)] - np.where(first > 0, cum[np.maximum(first - 1, 0)], 0.0), 0.0)
    n_try = 4 * nmb + 16
    sd = np.repeat(np.flatnonzero(has & (total > 0)), n_try)
    start = np.where(first > 0, cum[np.maximum(first - 1, 0)], 0.0)
    pick = np.searchsorted(cum, start[sd] + rng.random(len(sd)) * total[sd], side="right")
    pick = np.clip(pick, first[sd], last[sd] - 1)
    pts = _sample_in_triangles(tris[face[pick]], rng)
    d = np.linalg.norm(pts - pos[sd], axis=1)
    inside = d < eb
    tried = np.bincount(sd, minlength=k)
    hit = np.bincount(sd[inside], minlength=k)
    area_within = total * hit / np.maximum(tried, 1)
    sd, pts, d = sd[inside], pts[inside], d[inside]
    rank = np.arange(len(sd)) - np.searchsorted(sd, sd)  # sd is sorted
    take = rank < nmb
    sd, pts, d = sd[take], pts[take], d[take]
    if len(sd) == 0:
        return _NO_BALLS
    thickness = (eb - d) ** 2 / eb**2 * np.asarray(drips.water, dtype=np.float64)[sd] * kb
    return sheet_balls(pts, thickness, area_within[sd] / np.minimum(hit[sd], nmb))


def _grow_from_drips(drip, face, drip_face, mesh):
    """Of the (drip, face) candidate pairs, those connected to the drip's own face through
    candidate faces of the same drip (breadth-first, all drips at once); a drip whose own
    face is not a candidate keeps all its candidates.

    Returns
    -------
    drip, face : (p,) int
        Sorted by drip, then face.
    """
    n_faces = len(mesh.faces)
    key = np.sort(drip * n_faces + face)  # pairs are distinct
    drip, face = key // n_faces, key % n_faces
    start_key = np.arange(len(drip_face)) * n_faces + drip_face
    at = np.minimum(np.searchsorted(key, start_key), max(len(key) - 1, 0))
    seeded = (key[at] == start_key) if len(key) else np.zeros(len(start_key), dtype=bool)
    reached = ~seeded[drip]
    frontier = at[seeded]
    reached[frontier] = True
    adj = mesh.face_adjacency
    order = np.argsort(np.r_[adj[:, 0], adj[:, 1]], kind="stable")
    nbr = np.r_[adj[:, 1], adj[:, 0]][order]
    nbr_start = np.searchsorted(np.r_[adj[:, 0], adj[:, 1]][order], np.arange(n_faces + 1))
    while len(frontier):
        f = face[frontier]
        cnt = nbr_start[f + 1] - nbr_start[f]
        src = np.repeat(frontier, cnt)
        off = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        cand = drip[src] * n_faces + nbr[nbr_start[face[src]] + off]
        i = np.minimum(np.searchsorted(key, cand), len(key) - 1)
        new = np.zeros(len(key), dtype=bool)
        new[i[key[i] == cand]] = True
        new &= ~reached
        reached |= new
        frontier = np.flatnonzero(new)
    return drip[reached], face[reached]


def _sample_in_triangles(tris: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform random point in each triangle of ``tris`` (k, 3, 3)."""
    return np.einsum("kj,kjd->kd", _random_barycentric(len(tris), rng), tris)


def glaze_balls(flow_mesh: trimesh.Trimesh, water: WaterResult, glaze: dict,
                rng: np.random.Generator, min_sheet: float = 0.0) -> Balls:
    """``ngi`` balls spread at random over the wet surface (paper 4.4.4, Equation 3).

    Wet vertices are those of the water supply or with water > 0; wet faces have at least
    two. Points are drawn area-weighted and stratified over the wet faces (`spread_on_faces`),
    so the glaze sheet has fewer lumps and holes than independent draws give. Each ball
    makes the ice
    ``rgi = minGI + s [dUp lt + dDown (1 - lt)]`` thick, dUp and dDown interpolated:
    lt = 0 puts the thickness high up (water freezes where it lands), lt = 1 low down
    (it runs down before freezing), 0.5 evens it out.

    The sheet lies ``rgi`` on each side of the surface. Where ``2 rgi < min_sheet``, the ball
    sinks along the inward normal and grows so that the sheet is ``min_sheet`` thick while
    its outer face stays ``rgi`` above the surface: the extra ice hides inside the object,
    and a sheet thinner than a voxel or two would tear into holes under marching cubes.

    Parameters
    ----------
    flow_mesh : trimesh.Trimesh
        In meters, outward normals.
    water : WaterResult
        Per vertex of ``flow_mesh``.
    glaze : dict
        The resolved ``glaze`` group.
    rng : numpy.random.Generator
    min_sheet : float
        Least total thickness of the sheet, in meters (0: the sheet is ``2 rgi`` thick).

    Returns
    -------
    Balls
    """
    ngi = glaze["balls"]
    if ngi == 0:
        return _NO_BALLS
    wet = np.asarray(water.supply, dtype=bool) | (np.asarray(water.water) > 0)
    faces = flow_mesh.faces
    wet_faces = np.flatnonzero(wet[faces].sum(axis=1) >= 2)
    areas = flow_mesh.area_faces[wet_faces]
    if len(wet_faces) == 0 or areas.sum() <= 0:
        return _NO_BALLS
    tris = flow_mesh.triangles[wet_faces]
    pick = spread_on_faces(tris.mean(axis=1), areas, ngi, rng)
    fv = faces[wet_faces[pick]]
    bary = _random_barycentric(len(pick), rng)
    pts = (flow_mesh.vertices[fv] * bary[:, :, None]).sum(axis=1)
    d_up = (np.asarray(water.d_up, dtype=np.float64)[fv] * bary).sum(axis=1)
    d_down = (np.asarray(water.d_down, dtype=np.float64)[fv] * bary).sum(axis=1)
    lt = glaze["lifetime"]
    radius = glaze["min_radius"] + glaze["scale"] * (d_up * lt + d_down * (1 - lt))
    sink = np.maximum(0.5 * min_sheet - radius, 0.0)
    if sink.any():
        normal = (flow_mesh.vertex_normals[fv] * bary[:, :, None]).sum(axis=1)
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.where(norm > 1e-12, normal / np.maximum(norm, 1e-300), flow_mesh.face_normals[wet_faces[pick]])
        pts = pts - sink[:, None] * normal
        radius = radius + sink
    return sheet_balls(pts, radius, areas.sum() / ngi)


def spread_on_faces(centroids: np.ndarray, areas: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` faces drawn with probability proportional to area, stratified in space.

    Faces are put in Morton (Z-curve) order of their centroids and the ``n`` draws take one
    uniform value in each of ``n`` equal slices of the cumulative area: every point is still
    uniform over the surface, but neighbouring draws land apart, with none of the clumps
    and gaps of independent draws (which would show as lumps and holes in a sheet of balls).

    Parameters
    ----------
    centroids : (k, 3) float
    areas : (k,) float
    n : int
    rng : numpy.random.Generator

    Returns
    -------
    (n,) int
        Indices into ``centroids``.
    """
    lo, hi = centroids.min(axis=0), centroids.max(axis=0)
    cell = np.clip(((centroids - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.int64), 0, 1023)
    code = np.zeros(len(centroids), dtype=np.int64)
    for bit in range(10):
        for a in range(3):
            code |= ((cell[:, a] >> bit) & 1) << (3 * bit + a)
    order = np.argsort(code, kind="stable")
    cum = np.cumsum(areas[order])
    u = (np.arange(n) + rng.random(n)) * (cum[-1] / n)
    return order[np.minimum(np.searchsorted(cum, u, side="right"), len(order) - 1)]


def _random_barycentric(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) barycentric coordinates of uniform random points in a triangle."""
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1
    r1, r2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
    return np.stack([1 - r1 - r2, r1, r2], axis=1)


# --------------------------------------------------------------------------- field + polygonisation


@dataclass(frozen=True)
class Field:
    """Summed metaball field sampled on the blocks of a lattice that the balls reach.

    Lattice sample ``i`` (3 ints) lies at ``origin + i * voxel`` (meters); block ``b`` holds
    the samples ``b * B .. b * B + B - 1``; samples of absent blocks are zero.

    Attributes
    ----------
    origin : (3,) float64
    voxel : float
    level : float
    blocks : (k, 3) int64
        In `_block_keys` order.
    values : (k, B, B, B) float32
    """

    origin: np.ndarray
    voxel: float
    level: float
    blocks: np.ndarray
    values: np.ndarray


def polygonize(balls: Balls, voxel: float, level: float = LEVEL, block: int = BLOCK,
               name: str = "surface.voxel_size"):
    """The iso-surface ``field == level`` of summed Gaussian metaballs, welded and watertight.

    The lattice is cut into blocks of ``block^3`` samples; the field is evaluated only in
    blocks that some ball reaches (each ball cut off where it falls below
    ``CUTOFF * level``), every sample exactly once, and is zero elsewhere. Each block whose
    cells the surface crosses gets its upper neighbours' first sample planes as a halo and
    goes, packed side by side with the cells between blocks masked out, through one
    marching-cubes call per batch; vertices on block seams are welded by lattice edge.

    Parameters
    ----------
    balls : Balls
    voxel : float
        Grid spacing, in meters.
    level : float
        Iso level.
    block : int
        Samples per block edge.
    name : str
        The parameter that set ``voxel``, named in the error messages.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound triangles (normals point to lower field).

    Raises
    ------
    InputError
        When the voxel is so fine that the field would need more than ``_MAX_FIELD_BYTES``
        or ``_MAX_PAIRS`` (ball, block) pairs.
    """
    field = sample_field(balls, voxel, level, block, name)
    if field is None:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    lattice, faces = _march(field.values, field.blocks, level)
    return field.origin + lattice * voxel, faces


def sample_field(balls: Balls, voxel: float, level: float = LEVEL, block: int = BLOCK,
                 name: str = "surface.voxel_size") -> Field | None:
    """The field of ``balls`` on the blocks of the ``voxel`` lattice that they reach.

    See `polygonize`, which marches it; `fuse_fields` unites two of them.

    Returns
    -------
    Field or None
        None when no ball is left after the cut-off.

    Raises
    ------
    InputError
        A voxel too fine for the extent of the balls (``name`` is the parameter to raise).
    """
    keep = balls.weights > CUTOFF * level
    c, s, w = balls.centers[keep], balls.widths[keep], balls.weights[keep]
    if len(w) == 0:
        return None
    ext = s * np.sqrt(np.log(w / (CUTOFF * level)))
    origin = (np.floor(((c - ext[:, None]) / voxel).min(axis=0)) - 1) * voxel
    q = (c - origin) / voxel  # lattice coordinates, >= 1 inside every ball's reach
    sl, el = s / voxel, ext / voxel
    lo = np.ceil(q - el[:, None]).astype(np.int64)
    hi = np.floor(q + el[:, None]).astype(np.int64)
    # Refuse before allocating: (ball, block) pairs bound the work, blocks the field's memory.
    npairs = int(((hi // block - lo // block + 1)).prod(axis=1).sum())
    if npairs > _MAX_PAIRS:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much ice ({npairs} ball-block "
            f"pairs to evaluate, at most {_MAX_PAIRS}); raise {name}")
    ball, bc, starts, counts = _ball_block_pairs(q, el, lo, hi, block)
    nbytes = len(starts) * block**3 * 4
    if nbytes > _MAX_FIELD_BYTES:
        raise InputError(
            f"{name} = {voxel:g} m is too fine for this much ice: its field needs "
            f"{nbytes / 2**30:.1f} GiB (at most {_MAX_FIELD_BYTES / 2**30:.0f}); raise {name}")
    g = _axis_gaussians(q, sl, w, ball, bc, block)
    own = _block_fields(g, starts, counts, block)
    del g
    return Field(origin, voxel, level, bc[starts], own)


def _march(values: np.ndarray, blocks: np.ndarray, level: float):
    """Marching cubes over block fields (blocks absent from ``blocks`` count as zero).

    Parameters
    ----------
    values : (k, B, B, B) float32
    blocks : (k, 3) int
        Block coordinates, in `_block_keys` order.
    level : float

    Returns
    -------
    lattice : (n, 3) float64
        Vertices in lattice coordinates.
    faces : (m, 3) int64
        Welded across block seams, without degenerate faces.
    """
    block = values.shape[1]
    verts, faces, nverts = [], [], 0
    if len(values):
        for fields, where in _halo_blocks(values, blocks, level):
            v, f = _march_packed(_march_domain(fields, level), where, level**_POWER, block)
            verts.append(v)
            faces.append(f + nverts)
            nverts += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return _weld_lattice(np.concatenate(verts), np.concatenate(faces), block)


def _ball_block_pairs(q, el, lo, hi, block):
    """Every (ball, block) pair whose block the ball's cut-off sphere reaches, by block.

    Block ``b`` owns the samples ``b * block .. b * block + block - 1`` on each axis.

    Returns
    -------
    ball : (p,) int
    bc : (p, 3) int
        Block coordinates.
    starts, counts : (blocks,) int
        Pairs of each distinct block (in lexicographic order), in ``ball``/``bc`` order.
    """
    blo, bhi = lo // block, hi // block
    nbl = (bhi - blo + 1).astype(np.int32)
    per_ball = nbl.prod(axis=1)
    ball = np.repeat(np.arange(len(q), dtype=np.int32), per_ball)
    k = np.arange(len(ball), dtype=np.int32) - np.repeat((np.cumsum(per_ball) - per_ball).astype(np.int32), per_ball)
    nb = nbl[ball]
    bc = np.empty((len(ball), 3), dtype=np.int32)
    bc[:, 2] = k % nb[:, 2]
    k //= nb[:, 2]
    bc[:, 1] = k % nb[:, 1]
    bc[:, 0] = k // nb[:, 1]
    bc += blo.astype(np.int32)[ball]
    # Drop blocks that only the corners of a ball's box reach (outside its cut-off sphere).
    dist2 = np.zeros(len(ball), dtype=np.float32)
    for a in range(3):
        qa = q[:, a].astype(np.float32)[ball]
        first = (bc[:, a] * block).astype(np.float32)
        gap = np.maximum(np.maximum(first - qa, qa - (first + (block - 1))), 0.0)
        dist2 += gap * gap
    reach = dist2 <= (el.astype(np.float32) ** 2)[ball]
    ball, bc = ball[reach], bc[reach]
    key = _block_keys(bc)
    order = np.argsort(key, kind="stable")
    key, ball, bc = key[order], ball[order], bc[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, len(key)])
    return ball, bc.astype(np.int64), starts, counts


def _block_keys(bc):
    """One sortable int64 per block coordinate (k, 3) (coordinates are >= 0 and < 2^20)."""
    bc = np.asarray(bc, dtype=np.int64)
    return (bc[:, 0] << 42) | (bc[:, 1] << 21) | bc[:, 2]


def _axis_gaussians(q, sl, w, ball, bc, block):
    """Per pair and axis, the ball's 1-D Gaussian over the block's samples; the weight goes
    into x.

    Every sample belongs to exactly one block, so no sample can get two different values:
    a ball's tail simply ends at the blocks its cut-off sphere reaches.

    Returns
    -------
    g : three (block, pairs + 1) float32
        With a last zero column (padding for `_block_fields`).
    """
    j = np.arange(block, dtype=np.float32)[:, None]
    inv = (1.0 / sl[ball]).astype(np.float32)
    g = []
    for a in range(3):
        out = np.zeros((block, len(ball) + 1), np.float32)
        v = out[:, :-1]
        # (first sample of the block + j - centre) / width
        np.multiply(j, inv[None, :], out=v)
        v += ((bc[:, a] * block - q[ball, a]) * inv).astype(np.float32)[None, :]
        np.multiply(v, v, out=v)
        np.negative(v, out=v)
        np.exp(v, out=v)
        if a == 0:
            v *= w[ball].astype(np.float32)[None, :]
        g.append(out)
    return g


def _block_fields(g, starts, counts, block):
    """Field of every block's samples from the 1-D Gaussians of its balls.

    Blocks with about the same number of balls go through one stacked matrix product
    ``F[b, (x, y), z] = sum_n gx[b, x, n] gy[b, y, n] gz[b, n, z]``, in segments of at
    most ``_SEGMENT`` balls (OpenBLAS threads stall on long thin products here).

    Parameters
    ----------
    g : three (block, pairs + 1) float32
        Per axis, each pair's 1-D Gaussian over its block; the last column is 0.
    starts, counts : (blocks,) int
        Each block's pairs are ``starts[b] : starts[b] + counts[b]``.
    block : int

    Returns
    -------
    (blocks, block, block, block) float32
    """
    dummy = g[0].shape[1] - 1
    out = np.empty((len(starts), block, block, block), np.float32)
    flat_out = out.reshape(len(starts), -1)
    # Split each block's balls into the fewest segments of at most _SEGMENT, each padded
    # to a multiple of 4; blocks with the same segments share one product.
    nseg = np.maximum(-(-counts // _SEGMENT), 1)
    segs = 4 * -(-counts // (4 * nseg))
    shape = nseg * (_SEGMENT + 1) + segs  # sorts by (segments, segment length)
    by_count = np.argsort(shape, kind="stable")
    sorted_shape = shape[by_count]
    i = 0
    while i < len(by_count):
        seg = int(segs[by_count[i]])
        pad = int(nseg[by_count[i]]) * seg
        j = int(np.searchsorted(sorted_shape, sorted_shape[i], side="right"))
        j = min(j, i + max(1, _FIELD_BATCH // (block * block * pad)))
        blk = by_count[i:j]
        lane = np.arange(pad)
        idx = np.where(lane < counts[blk, None], starts[blk, None] + lane, dummy).reshape(-1, seg)
        gx, gy, gz = (gi[:, idx].transpose(1, 0, 2) for gi in g)  # (blocks * segments, B, seg)
        xy = (gx[:, :, None, :] * gy[:, None, :, :]).reshape(len(idx), block * block, seg)
        f = np.matmul(xy, gz.transpose(0, 2, 1)).reshape(len(blk), pad // seg, -1)
        flat_out[blk] = f[:, 0] if pad == seg else f.sum(axis=1)
        i = j
    return out


def _march_domain(fields, level):
    """``fields ** _POWER`` in place, pushed at least ``_NUDGE`` (relative) off the level.

    Marching cubes interpolates linearly along cell edges; F^p with p = KAPPA^2 / 2 has its
    inflection at the surface of a chain, so there it is nearly exact. The nudge keeps every
    vertex off the grid corners (no zero-area faces) and, being a function of the one
    value each sample has, cannot make two blocks disagree on a shared sample.
    """
    np.maximum(fields, np.float32(CUTOFF * level), out=fields)
    np.log(fields, out=fields)
    fields *= np.float32(_POWER)
    np.exp(fields, out=fields)
    t_level = np.float32(level**_POWER)
    nudge = np.float32(_NUDGE * level**_POWER)
    near = np.abs(fields - t_level) < nudge
    fields[near] = np.where(fields[near] < t_level, t_level - nudge, t_level + nudge)
    return fields


def _halo_blocks(own, blocks, level):
    """Blocks of ``(B+1)^3`` samples (own samples plus the first planes of the upper
    neighbours, zero where a neighbour has no field) that the level crosses, in batches.

    A block without field of its own is marched too where an upper neighbour's first samples
    rise above the level (balls only a voxel or two wide reach the level next to the edge
    of their cut-off box).

    Yields
    ------
    fields : (k, B+1, B+1, B+1) float32
    blocks : (k, 3) int
        Block coordinates.
    """
    n, b = len(own), own.shape[1]
    keys = _block_keys(blocks)  # sorted: blocks come from _ball_block_pairs
    offsets = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1))
    # A lower neighbour (face, edge or corner) without field still has cells to march where
    # our first plane, line or corner sample along its offset rises above the level.
    lower = []
    for off in offsets:
        first = own[(slice(None),) + tuple(0 if o else slice(None) for o in off)]
        high = first.reshape(n, -1).max(axis=1) > level
        lower.append(blocks[high] - np.array(off))
    extra = np.concatenate(lower)
    extra = extra[(extra >= 0).all(axis=1)]
    if len(extra):
        extra = np.unique(extra, axis=0)
        extra = extra[~np.isin(_block_keys(extra), keys)]
    cand = np.concatenate([blocks, extra]) if len(extra) else blocks
    slot_self = np.r_[np.arange(n), np.full(len(cand) - n, -1)]

    def slot(offset):
        k = _block_keys(cand + offset)
        i = np.minimum(np.searchsorted(keys, k), n - 1)
        return np.where(keys[i] == k, i, -1)

    parts = [((0, 0, 0), slot_self)] + [(off, slot(np.array(off))) for off in offsets]
    batch = max(1, _MARCH_BATCH // (b + 1) ** 3)
    for i in range(0, len(cand), batch):
        sl = slice(i, i + batch)
        halo = np.zeros((len(cand[sl]), b + 1, b + 1, b + 1), np.float32)
        for off, s in parts:
            rows = np.flatnonzero(s[sl] >= 0)
            if len(rows) == 0:
                continue
            # Along each offset axis the neighbour gives its first plane to our last one.
            target = tuple(b if o else slice(0, b) for o in off)
            source = tuple(0 if o else slice(0, b) for o in off)
            halo[(rows,) + target] = own[(s[sl][rows],) + source]
        flat = halo.reshape(len(halo), -1)
        cross = (flat.max(axis=1) > level) & (flat.min(axis=1) < level)
        if cross.any():
            yield halo[cross], cand[sl][cross]


def _march_packed(fields: np.ndarray, blocks: np.ndarray, level: float, block: int):
    """Marching cubes over halo blocks packed into one volume; lattice-coordinate vertices."""
    n = len(fields)
    n1 = block + 1
    px = int(math.ceil(n ** (1 / 3)))
    py = int(math.ceil(math.sqrt(n / px)))
    pz = int(math.ceil(n / (px * py)))
    pad = px * py * pz - n
    if pad:
        fields = np.concatenate([fields, np.zeros((pad, n1, n1, n1), dtype=np.float32)])
    vol = fields.reshape(px, py, pz, n1, n1, n1).transpose(0, 3, 1, 4, 2, 5).reshape(px * n1, py * n1, pz * n1)
    # Cells between two packed blocks must not march; skimage's mask[i] governs the cell
    # from sample i - 1 to i, so mask out each block's first sample plane.
    mx, my, mz = ((np.arange(p * n1) % n1) != 0 for p in (px, py, pz))
    mask = mx[:, None, None] & my[None, :, None] & mz[None, None, :]
    v, f, _, _ = marching_cubes(vol, level=level, mask=mask, gradient_direction="ascent")
    v = v.astype(np.float64)
    cell = np.minimum(np.floor(v / n1).astype(np.int64), np.array([px, py, pz]) - 1)
    local = v - cell * n1
    # Vertices on lattice edges again, in float64 from the edge's two samples and rounded
    # from block-local coordinates: an edge then gets the same bits whatever batch or
    # packing marched it (`fuse_fields` welds on them).
    base = np.floor(v)
    frac = v - base
    edge = np.flatnonzero((frac > 0).sum(axis=1) == 1)
    axis = np.argmax(frac[edge], axis=1)
    i0 = base[edge].astype(np.int64)
    i1 = i0.copy()
    i1[np.arange(len(edge)), axis] += 1
    g0 = vol[i0[:, 0], i0[:, 1], i0[:, 2]].astype(np.float64)
    g1 = vol[i1[:, 0], i1[:, 1], i1[:, 2]].astype(np.float64)
    t = np.clip((level - g0) / np.where(g1 != g0, g1 - g0, 1.0), 0.0, 1.0)
    local[edge, axis] = (i0 - cell[edge] * n1)[np.arange(len(edge)), axis] + t
    which = (cell[:, 0] * py + cell[:, 1]) * pz + cell[:, 2]
    return blocks[which] * block + local, f.astype(np.int64)


def _weld_lattice(lattice: np.ndarray, faces: np.ndarray, block: int):
    """Merge the copies of vertices on block seams; drop degenerate faces.

    A marching-cubes vertex lies on a lattice edge (one fractional coordinate) or, for some
    of Lewiner's cases, inside a cell. Only edges in a seam plane (a coordinate that is a
    multiple of ``block``) are marched by more than one block; their copies share the
    edge's key.
    """
    base = np.floor(lattice)
    frac = lattice - base
    on_seam = ((frac == 0) & (base % block == 0)).any(axis=1)
    seam = np.flatnonzero(on_seam)
    index = np.arange(len(lattice))
    if len(seam):
        fs, bs = frac[seam], base[seam].astype(np.int64)
        nfrac = (fs > 0).sum(axis=1)
        key = (_block_keys(bs - bs.min(axis=0)) << 2) | np.where(nfrac == 1, np.argmax(fs, axis=1), 3)
        key = np.where(nfrac >= 2, -1 - np.arange(len(key)), key)
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        index[seam] = seam[first][inverse.reshape(-1)]
    faces = index[faces]
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[ok]
    used = np.zeros(len(lattice), dtype=bool)
    used[faces] = True
    remap = np.cumsum(used) - 1
    return lattice[used], remap[faces]


def ice_mesh(ice: Balls, coat: Balls, voxel: float, coat_voxel: float):
    """The icicles with their bases, and the glaze, as one watertight mesh.

    With ``coat_voxel <= voxel`` (or no glaze) all balls add into one field polygonised at
    ``voxel``: the glaze fuses smoothly with the bases. Otherwise the icicles and bases
    are polygonised at ``voxel`` (which the tip radius needs), the glaze alone at the
    coarser ``coat_voxel`` (it covers the whole wet surface, so its face count rules the
    mesh: about ``(coat_voxel / voxel)^2`` times fewer faces), and the two closed surfaces
    are joined by a boolean union (`fuse_fields`).

    Parameters
    ----------
    ice, coat : Balls
        Icicle chains and bases; glaze.
    voxel, coat_voxel : float
        ``surface.voxel_size`` and ``glaze.voxel_size``, in meters.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound, watertight.
    """
    if len(coat) == 0 or coat_voxel <= voxel:
        return polygonize(concat_balls(ice, coat), voxel)
    coat_field = sample_field(coat, coat_voxel, name="glaze.voxel_size")
    return fuse_fields(sample_field(ice, voxel), coat_field)


def fuse_fields(a: Field | None, b: Field | None):
    """Boolean union of the iso-surfaces of two sampled fields, each on its own lattice.

    Both are marched whole. The union only cuts them where they come close, so only there
    does it run (manifold3d): each field is marched again with its samples zeroed outside
    the tiles near the other surface (`_margin`), which closes it with caps out of the
    other's reach; the caps are cut off the union and the rest welds, bit for bit, to the
    faces of the whole meshes outside those tiles, less those wholly inside the other solid
    (nearest-sample test). Should a check fail (a face there half inside, a seam that does
    not close), the whole meshes go through the boolean instead (`union_meshes`).

    Parameters
    ----------
    a, b : Field or None
        From `sample_field`; None is an empty field.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound, watertight.
    """
    parts = []
    for f in (a, b):
        if f is not None:
            lattice, faces = _march(f.values, f.blocks, f.level)
            if len(faces):
                parts.append((f, f.origin + lattice * f.voxel, lattice, faces))
    if len(parts) < 2:
        return (parts[0][1], parts[0][3]) if parts else (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    fused = _local_union(*parts)
    if fused is None:
        fused = union_meshes([(p[1], p[3]) for p in parts])
    return fused


def _margin(field: Field, other: Field) -> float:
    """How far the cells of ``field`` left out of the union must lie from ``other``'s
    vertices.

    A point of the other surface lies within one of its voxels of a vertex of it (a
    marching-cubes triangle fits in a cell), and a cell spans one cell diagonal, so a cell
    with a sample this far from the other's vertices stays more than half of the other's
    cell diagonal off the other surface: out of its reach, and on the side of it that the
    nearest sample of the other field says (`_inside`).
    """
    return 1.05 * (math.sqrt(3) * field.voxel + (1 + 0.5 * math.sqrt(3)) * other.voxel)


def _local_union(a, b):
    """`fuse_fields` near where the surfaces meet; None when a check fails.

    ``a``, ``b``: (field, vertices in meters, vertices in lattice coordinates, faces).
    """
    sides = []
    for (field, verts, lattice, faces), (other, other_verts, *_) in ((a, b), (b, a)):
        tiles = _near_tiles(field, other_verts, _margin(field, other))
        if tiles is None:
            return None
        inner = _inner_faces(lattice, faces, *tiles)
        values, blocks = _restrict(field, *tiles)
        r_lattice, r_faces = _march(values, blocks, field.level)
        r_inner = _inner_faces(r_lattice, r_faces, *tiles)
        sides.append((field, verts, faces, inner, field.origin + r_lattice * field.voxel, r_faces, r_inner))
    # The whole mesh's faces in cells that reach out of the region lie off the other
    # surface: each lies wholly inside the other solid (the union covers it: dropped) or
    # wholly outside (kept as it is).
    outside = []
    for (_, verts, faces, inner, *_), other in zip(sides, (sides[1][0], sides[0][0])):
        out = np.flatnonzero(~inner)
        used = _used(faces[out], len(verts))
        covered = np.zeros(len(verts), dtype=bool)
        covered[used] = _inside(other, verts[used])
        count = covered[faces[out]].sum(axis=1)
        if ((count > 0) & (count < 3)).any():
            return None
        outside.append(out[count == 0])
    u_verts, u_faces, source, origin = _manifold_union([(s[4], s[5]) for s in sides])
    keep = np.zeros(len(u_faces), dtype=bool)
    for i, side in enumerate(sides):
        mine = source == i
        keep[mine] = side[6][origin[mine]]
    nu = len(u_verts)
    u_edge = np.flatnonzero(_used(u_faces[keep], nu) & _used(u_faces[~keep], nu))  # where caps were cut off
    u_faces = u_faces[keep]

    # One vertex list: side a, side b, the union; the seams weld on exact positions.
    (_, va, fa, ia, *_), (_, vb, fb, ib, *_) = sides
    na, nb = len(va), len(vb)
    seam = [np.flatnonzero(_used(f[i], len(v)) & _used(f[~i], len(v))) + off
            for v, f, i, off in ((va, fa, ia, 0), (vb, fb, ib, na))]
    cand = np.concatenate(seam + [u_edge + na + nb])
    verts = np.concatenate([va, vb, u_verts])
    _, first, inverse = np.unique(np.ascontiguousarray(verts[cand]).view(np.dtype((np.void, 24))).reshape(-1),
                                  return_index=True, return_inverse=True)
    index = np.arange(len(verts))
    index[cand] = cand[first][inverse.reshape(-1)]
    faces = index[np.concatenate([fa[outside[0]], fb[outside[1]] + na, u_faces + na + nb])]
    if ((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])).any():
        return None
    # Away from the seams each part is closed already (the marched meshes and the union).
    touched = np.zeros(len(verts), dtype=bool)
    touched[index[cand]] = True
    if not _closed_around(faces, touched):
        return None
    used = _used(faces, len(verts))
    return verts[used], (np.cumsum(used) - 1)[faces]


def _used(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertices that ``faces`` use."""
    used = np.zeros(n, dtype=bool)
    used[faces] = True
    return used


def _near_tiles(field: Field, points: np.ndarray, margin: float):
    """Tiles (cubes of ``tile^3`` samples) of ``field``'s lattice within ``margin`` of any
    of ``points`` (k, 3) (meters), as a dense boolean grid; None if it would be too big.

    Returns
    -------
    region : (tx, ty, tz) bool
        Every tile with a point within ``margin`` is in it (some a little farther are too).
    lo : (3,) int
        Tile coordinates of ``region[0, 0, 0]``.
    tile : int
        Samples per tile edge.
    """
    block = field.values.shape[1]
    # Tiles about half the margin: finer ones make bigger grids, coarser ones wider regions.
    finest = min(margin / (2 * field.voxel), block)
    for tile in (t for t in range(1, block + 1) if block % t == 0 and 2 * t > finest):
        per = block // tile
        k = int(math.ceil(margin / (tile * field.voxel)))
        lo = (field.blocks.min(axis=0) - 1) * per - k  # from the (empty) lower neighbours' tiles
        shape = (field.blocks.max(axis=0) + 2) * per + k - lo
        if int(np.prod(shape)) <= _MAX_TILES:
            break
    else:
        return None
    t = np.floor((points - field.origin) / (field.voxel * tile)).astype(np.int64) - lo
    t = t[((t >= 0) & (t < shape)).all(axis=1)]
    occupied = np.zeros(tuple(shape), dtype=np.uint8)
    occupied[t[:, 0], t[:, 1], t[:, 2]] = 1
    # A tile j tiles away from a point's tile is at least (j - 1) tile edges away from it.
    return ndimage.maximum_filter(occupied, size=2 * k + 1, mode="constant") > 0, lo, tile


def _inner_faces(lattice: np.ndarray, faces: np.ndarray, region, lo, tile) -> np.ndarray:
    """Faces whose marching-cubes cell has all 8 samples in ``region``: marching the
    restricted field gives them bit for bit.

    A face's cell is the floor of its vertices' least coordinates, the same for all faces
    of a cell, so a cell's faces (and the vertex some cells add inside) never split between
    the two sides of the seam. A cell across tiles asks for the 2 x 2 x 2 tiles from its own.
    """
    corner = np.floor(lattice).astype(np.int32)
    cell = np.minimum(np.minimum(corner[faces[:, 0]], corner[faces[:, 1]]), corner[faces[:, 2]])
    t = cell // tile - lo.astype(np.int32)
    across = (cell % tile == tile - 1).any(axis=1)
    box = region.copy()
    for axis in range(3):
        head = [slice(None)] * 3
        tail = [slice(None)] * 3
        head[axis], tail[axis] = slice(0, -1), slice(1, None)
        box[tuple(head)] &= box[tuple(tail)]
        tail[axis] = -1
        box[tuple(tail)] = False
    ok = ((t >= 0) & (t < np.array(region.shape))).all(axis=1)
    inner = np.zeros(len(faces), dtype=bool)
    t, across = t[ok], across[ok]
    inner[ok] = np.where(across, box[t[:, 0], t[:, 1], t[:, 2]], region[t[:, 0], t[:, 1], t[:, 2]])
    return inner


def _restrict(field: Field, region, lo, tile):
    """``field``'s blocks that reach ``region``, with their samples outside it zeroed.

    Returns
    -------
    values : (k, B, B, B) float32
    blocks : (k, 3) int64
    """
    block = field.values.shape[1]
    per = block // tile
    first = field.blocks * per - lo
    o = np.arange(per)
    mask = region[first[:, 0, None, None, None] + o[:, None, None],
                  first[:, 1, None, None, None] + o[None, :, None],
                  first[:, 2, None, None, None] + o[None, None, :]]
    keep = mask.reshape(len(mask), -1).any(axis=1)
    mask = mask[keep]
    for axis in (1, 2, 3):
        mask = np.repeat(mask, tile, axis=axis)
    return field.values[keep] * mask, field.blocks[keep]


def _inside(field: Field, points: np.ndarray) -> np.ndarray:
    """Whether the field's nearest sample to each point (n, 3) (meters) is above its level."""
    block = field.values.shape[1]
    s = np.rint((points - field.origin) / field.voxel).astype(np.int64)
    bc = s // block
    ok = ((bc >= 0) & (bc < 2**20)).all(axis=1)
    keys = _block_keys(field.blocks)
    key = _block_keys(np.where(ok[:, None], bc, 0))
    i = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
    ok &= keys[i] == key
    r = s - bc * block
    return ok & (field.values[i, r[:, 0], r[:, 1], r[:, 2]] > field.level)


def _closed_around(faces: np.ndarray, touched: np.ndarray) -> bool:
    """Whether every edge with an end in ``touched`` (per vertex) joins exactly two faces
    that cross it in opposite directions."""
    f = faces[touched[faces].any(axis=1)]
    e = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)
    e = e[touched[e].any(axis=1)]
    n = len(touched)
    key = np.sort(e[:, 0] * n + e[:, 1])
    back = np.sort(e[:, 1] * n + e[:, 0])
    return bool((np.diff(key) != 0).all() and np.array_equal(key, back))


def union_meshes(parts):
    """Boolean union of closed meshes (manifold3d), as one watertight mesh.

    Parameters
    ----------
    parts : sequence of ((n, 3) float, (m, 3) int)
        Closed, outward-wound meshes in meters; empty ones are skipped.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Outward-wound, watertight.

    Raises
    ------
    ValueError
        A part that is not a closed, oriented 2-manifold.
    """
    vertices, faces, _, _ = _manifold_union(parts)
    return vertices, faces


def _manifold_union(parts):
    """`union_meshes`, with each face's source: the index of its part and of its face there.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    source, origin : (m,) int64
    """
    import manifold3d

    solids, index, ids = [], [], []
    first_id = manifold3d.Manifold.reserve_ids(len(parts))
    for i, (v, f) in enumerate(parts):
        if len(f) == 0:
            continue
        # One face id per triangle: manifold3d then neither merges nor re-triangulates
        # coplanar neighbours, so untouched triangles come out as they went in.
        solid = manifold3d.Manifold(manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(v, dtype=np.float64),
            tri_verts=np.ascontiguousarray(f, dtype=np.uint64),
            run_index=np.array([0, 3 * len(f)], dtype=np.uint64),
            run_original_id=np.array([first_id + i], dtype=np.uint32),
            face_id=np.arange(len(f), dtype=np.uint64)))
        if solid.status() != manifold3d.Error.NoError:
            raise ValueError(f"mesh {i} of the union is not a closed oriented manifold: {solid.status()}")
        solids.append(solid)
        index.append(i)
        ids.append(first_id + i)
    if not solids:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids = np.array(ids)
    union = solids[0] if len(solids) == 1 else manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if union.status() != manifold3d.Error.NoError:
        raise ValueError(f"the union of {len(solids)} meshes failed: {union.status()}")
    out = union.to_mesh64()
    vertices = np.array(out.vert_properties, dtype=np.float64).reshape(-1, max(out.vert_properties.shape[1], 3))[:, :3]
    faces = np.array(out.tri_verts, dtype=np.int64).reshape(-1, 3)
    runs = np.array(out.run_index, dtype=np.int64) // 3
    run_source = np.array(index)[np.searchsorted(ids, np.array(out.run_original_id, dtype=np.int64))]
    source = np.repeat(run_source, np.diff(runs))
    origin = np.array(out.face_id, dtype=np.int64)
    return vertices, faces, source, origin


# --------------------------------------------------------------------------- tubes


def tube_mesh(traj: TrajectoryResult, surface: dict, gravity=(0.0, -1.0, 0.0), ring: int = 12,
              cap_rings: int = 4):
    """Each branch as a closed tube: Equation 1's profile swept along the branch with
    rotation-minimising frames, a hemisphere of the tip radius at the tip and one of the
    base radius at the base (paper 6.1: the icicles' mesh directly, no metaballs).

    Parameters
    ----------
    traj : TrajectoryResult
    surface : dict
        The resolved ``surface`` group.
    gravity : (3,) float
        Each tube's first frame starts from gravity (seams line up from run to run).
    ring : int
        Vertices per ring.
    cap_rings : int
        Rings in each hemisphere, besides its pole.

    Returns
    -------
    vertices : (n, 3) float64
        In meters.
    faces : (m, 3) int64
        Outward-wound; each branch's tube is closed (watertight) on its own.
    """
    tip = surface["tip_radius"]
    prof = (tip, surface["growth_ratio"], surface["ripple_amplitude"], surface["ripple_frequency"])
    x_pt, lengths = _branch_lengths(traj)
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if len(branches) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    step = tip
    if prof[2] > 0 and prof[3] > 0:
        step = min(step, 2 * math.pi / prof[3] / 6)
    L = lengths[branches]
    n = np.maximum(np.ceil(L / step).astype(np.int64), 1) + 1  # body rings per tube
    rb = np.repeat(np.arange(len(branches)), n)
    first = np.cumsum(n) - n
    rk = np.arange(n.sum()) - first[rb]
    xr = rk * (L / (n - 1))[rb]
    centre, _ = _points_along(traj, x_pt, lengths, branches[rb], xr)
    radius = profile_radius(xr, L[rb], *prof)
    # Tangents by central differences within each tube (one-sided at its ends).
    last = first + n - 1
    ahead = centre[np.minimum(np.arange(len(rb)) + 1, last[rb])]
    behind = centre[np.maximum(np.arange(len(rb)) - 1, first[rb])]
    tangent = ahead - behind
    norm = np.linalg.norm(tangent, axis=1, keepdims=True)
    down = np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity)
    tangent = np.where(norm > 0, tangent / np.maximum(norm, 1e-300), down)
    normal = _transport_frames(centre, tangent, first, n, gravity)
    binormal = np.cross(tangent, normal)

    # Rings in order along each tube: base hemisphere, body, tip hemisphere.
    dphi = 0.5 * math.pi / (cap_rings + 1)
    k = len(branches)
    per = n + 2 * cap_rings
    start = np.cumsum(per) - per
    total = int(per.sum())
    rc, rr = np.empty((total, 3)), np.empty(total)
    rn, rbn = np.empty((total, 3)), np.empty((total, 3))
    body = start[rb] + cap_rings + rk
    rc[body], rr[body], rn[body], rbn[body] = centre, radius, normal, binormal
    for i in range(cap_rings):
        for end, sign, at in ((first, -1.0, start + i), (last, 1.0, start + cap_rings + n + i)):
            phi = (cap_rings - i) * dphi if sign < 0 else (i + 1) * dphi
            rc[at] = centre[end] + sign * math.sin(phi) * radius[end, None] * tangent[end]
            rr[at] = math.cos(phi) * radius[end]
            rn[at], rbn[at] = normal[end], binormal[end]
    theta = np.arange(ring) * (2 * math.pi / ring)
    verts = rc[:, None, :] + rr[:, None, None] * (np.cos(theta)[None, :, None] * rn[:, None, :]
                                                  + np.sin(theta)[None, :, None] * rbn[:, None, :])
    poles = np.concatenate([centre[first] - radius[first, None] * tangent[first],
                            centre[last] + radius[last, None] * tangent[last]])
    vertices = np.concatenate([verts.reshape(-1, 3), poles])

    # Quads between consecutive rings of a tube, fans to the poles.
    has_next = np.ones(total, dtype=bool)
    has_next[start + per - 1] = False
    lower = np.flatnonzero(has_next)
    j = np.arange(ring)
    a = lower[:, None] * ring + j
    b = lower[:, None] * ring + (j + 1) % ring
    quads = np.concatenate([np.stack([a, b, b + ring], -1).reshape(-1, 3),
                            np.stack([a, b + ring, a + ring], -1).reshape(-1, 3)])
    pole_base = total * ring + np.arange(k)
    pole_tip = total * ring + k + np.arange(k)
    ring0 = start[:, None] * ring
    ring1 = (start + per - 1)[:, None] * ring
    fan_b = np.stack([np.repeat(pole_base[:, None], ring, 1), ring0 + (j + 1) % ring, ring0 + j], -1)
    fan_t = np.stack([np.repeat(pole_tip[:, None], ring, 1), ring1 + j, ring1 + (j + 1) % ring], -1)
    faces = np.concatenate([quads, fan_b.reshape(-1, 3), fan_t.reshape(-1, 3)]).astype(np.int64)
    return vertices, faces


def _points_along(traj: TrajectoryResult, x_pt, lengths, branch, x):
    """Points at arc length ``x`` (k,) along branches ``branch`` (k,), with the unit direction
    of the polyline segment there.

    Returns
    -------
    points, directions : (k, 3) float
    """
    pts = np.asarray(traj.points, dtype=np.float64)
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    counts = np.diff(off)
    # All branches laid end to end with a gap of 1 m: one monotone abscissa for np.interp.
    gap = np.concatenate([[0.0], np.cumsum(lengths + 1.0)[:-1]])
    xg = x_pt + np.repeat(gap, counts)
    tg = np.asarray(x, dtype=np.float64) + gap[branch]
    points = np.stack([np.interp(tg, xg, pts[:, a]) for a in range(3)], axis=1)
    lo, hi = off[branch], off[branch + 1] - 1
    seg = np.clip(np.searchsorted(xg, tg, side="right") - 1, lo, np.maximum(hi - 1, lo))
    d = pts[np.minimum(seg + 1, hi)] - pts[seg]
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return points, np.where(norm > 0, d / np.maximum(norm, 1e-300), [[0.0, -1.0, 0.0]])


def _transport_frames(centre, tangent, first, n, gravity) -> np.ndarray:
    """Rotation-minimising normals along many polylines at once (double reflection, Wang et
    al. 2008); polyline ``i`` is ``centre[first[i]:first[i] + n[i]]``. Each starts from
    gravity made perpendicular to its first tangent."""
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    t0 = tangent[first]
    n0 = g - (t0 @ g)[:, None] * t0
    bad = np.linalg.norm(n0, axis=1) < 1e-6
    if bad.any():
        n0[bad] = _perpendicular_frame(t0[bad])[0]
    normal = np.empty_like(centre)
    normal[first] = n0 / np.linalg.norm(n0, axis=1, keepdims=True)
    for step in range(int(n.max()) - 1):
        live = first[n > step + 1] + step
        nxt = live + 1
        v1 = centre[nxt] - centre[live]
        c1 = np.maximum(np.einsum("ij,ij->i", v1, v1), 1e-300)[:, None]
        r_l = normal[live] - (2 / c1) * np.einsum("ij,ij->i", v1, normal[live])[:, None] * v1
        t_l = tangent[live] - (2 / c1) * np.einsum("ij,ij->i", v1, tangent[live])[:, None] * v1
        v2 = tangent[nxt] - t_l
        c2 = np.einsum("ij,ij->i", v2, v2)[:, None]
        r = r_l - (2 / np.maximum(c2, 1e-300)) * np.einsum("ij,ij->i", v2, r_l)[:, None] * v2
        r = np.where(c2 > 1e-30, r, r_l)
        r -= np.einsum("ij,ij->i", r, tangent[nxt])[:, None] * tangent[nxt]
        normal[nxt] = r / np.linalg.norm(r, axis=1, keepdims=True)
    return normal


# --------------------------------------------------------------------------- measurements


def measure_icicles(vertices: np.ndarray, faces: np.ndarray, traj: TrajectoryResult,
                    surface: dict, sample_step: float = 0.001):
    """Physical plausibility of the icicles, measured on the ice mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        In meters.
    faces : (m, 3) int
    traj : TrajectoryResult
    surface : dict
        The resolved ``surface`` group (only ``ripple_amplitude`` is read: 0 means no ripple).
    sample_step : float
        Spacing of the radius samples along each trunk, in meters.

    Returns
    -------
    tip_radius_mm : float
        Median over trunks of the distance from the tip point to the ice ahead of it (median
        over the drop's mesh vertices, which lie on the iso-surface).
    length_to_diameter : (i,) float
        Per trunk, its length over twice the base radius of a line fitted to its radius
        (distance from the axis to the nearest vertex) between 30 % and 90 % of its length,
        taken at x = 0; nan for a trunk with fewer than 4 samples there (shorter than
        ``4 sample_step / 0.6``) or whose fitted base radius is not positive.
    ripple_wavelength_cm : float
        Peak of the trunks' radius spectra (quadratic trend removed, Hann window, each trunk
        normalised), in centimeters; nan when the ripple amplitude is 0 or no trunk spans
        eight samples.
    """
    nan = float("nan")
    off = np.asarray(traj.branch_offsets, dtype=np.int64)
    trunks = np.flatnonzero(np.asarray(traj.branch_parent) < 0)
    trunks = trunks[np.diff(off)[trunks] > 0]
    if len(trunks) == 0 or len(faces) == 0:
        return nan, np.full(len(trunks), np.nan), nan
    x_pt, lengths = _branch_lengths(traj)
    pts = np.asarray(traj.points, dtype=np.float64)
    tree = cKDTree(vertices, balanced_tree=False, compact_nodes=False)

    tips = pts[off[trunks + 1] - 1]
    direction = tips - pts[np.maximum(off[trunks + 1] - 2, off[trunks])]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-300)
    tip_d = _tip_radius(tips, direction, vertices, tree)
    tip_mm = float(np.nanmedian(tip_d) * 1000) if np.isfinite(tip_d).any() else nan

    # Radius samples along the free part of every trunk, all queried at once.
    L = lengths[trunks]
    n = np.maximum((0.6 * L / sample_step).astype(np.int64), 0) + 1
    ok = n >= 4
    n = np.where(ok, n, 0)
    owner = np.repeat(np.arange(len(trunks)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    x = (0.3 * L)[owner] + k * sample_step
    axis, _ = _points_along(traj, x_pt, lengths, trunks[owner], x)
    r = tree.query(axis)[0] if len(axis) else np.zeros(0)

    ratios = np.full(len(trunks), np.nan)
    spectra = []
    for j in np.flatnonzero(ok):
        sel = owner == j
        xj, rj = x[sel], r[sel]
        A = np.stack([np.ones_like(xj), L[j] - xj], axis=1)
        (a0, slope), *_ = np.linalg.lstsq(A, rj, rcond=None)
        base = a0 + max(slope, 0.0) * L[j]
        if base > 0:
            ratios[j] = L[j] / (2 * base)
        if len(xj) >= 8:
            u = (xj - xj.mean()) / max(np.ptp(xj), 1e-300)
            trend = np.polyval(np.polyfit(u, rj, 2), u)
            spectra.append((rj - trend) * np.hanning(len(rj)))
    wavelength = nan
    if surface["ripple_amplitude"] > 0 and spectra:
        wavelength = _dominant_period(spectra, sample_step) * 100
    return tip_mm, ratios, wavelength


def _tip_radius(points, directions, vertices, tree):
    """Per tip point (p, 3) with its unit growth direction: the median distance to the mesh
    vertices (which lie on the iso-surface) ahead of the tip and within 1.5 times the
    nearest one, i.e. the radius of the drop that closes the icicle."""
    d_near, _ = tree.query(points)
    out = np.full(len(points), np.nan)
    for i, idx in enumerate(tree.query_ball_point(points, 1.5 * d_near)):
        rel = vertices[np.asarray(idx, dtype=np.int64)] - points[i]
        ahead = rel @ directions[i] >= 0
        if ahead.any():
            out[i] = np.median(np.linalg.norm(rel[ahead], axis=1))
    return out


def _dominant_period(profiles, step):
    """Period (m) at the peak of the summed, per-profile normalised power spectra of
    ``profiles`` (list of 1-D arrays sampled every ``step`` meters), past the lowest bins."""
    size = 1 << int(math.ceil(math.log2(4 * max(len(p) for p in profiles))))
    freq = np.fft.rfftfreq(size, step)
    power = np.zeros(len(freq))
    for p in profiles:
        spec = np.abs(np.fft.rfft(p, size)) ** 2
        if spec.sum() > 0:
            power += spec / spec.sum()
    # Periods longer than half the longest profile are trend, not ripple.
    longest = max(len(p) for p in profiles) * step
    power[freq < 2.0 / longest] = 0.0
    if not power.any():
        return float("nan")
    return float(1.0 / freq[np.argmax(power)])


# --------------------------------------------------------------------------- the stage


def build_ice(object_mesh: trimesh.Trimesh, flow_mesh: trimesh.Trimesh, water: WaterResult,
              drips: DripResult, trajectories: TrajectoryResult, surface: dict, glaze: dict,
              gravity: np.ndarray, rng: np.random.Generator) -> IceResult:
    """Stage 4: icicles, their bases and glaze ice as one mesh (paper 4.4).

    ``surface["mode"] == "metaballs"``: one watertight mesh of the icicle chains, the
    bases and the glaze (`ice_mesh`: the glaze on its own coarser lattice, joined by a
    boolean union, or all in one field). ``"tubes"``: each branch as its own closed tube
    (`tube_mesh`), without bases or glaze: an instant preview.

    Parameters
    ----------
    object_mesh : trimesh.Trimesh
        The object, in meters; the drip points lie on it and the bases grow on it.
    flow_mesh : trimesh.Trimesh
        The surface stages 1-2 ran on (the object or its proxy); the glaze grows on it.
    water : WaterResult
        Per vertex of ``flow_mesh``.
    drips : DripResult
        Drip points on ``object_mesh``.
    trajectories : TrajectoryResult
        Branch polylines, base to tip, in meters.
    surface, glaze : dict
        ``params.resolve()["surface"]`` and ``["glaze"]``.
    gravity : (3,) float
        Direction of gravity (orients the first frame of each tube).
    rng : numpy.random.Generator
        Noise, base and glaze ball positions.

    Returns
    -------
    IceResult

    Raises
    ------
    ValueError
        Inputs of inconsistent shapes.
    InputError
        A voxel size (``surface.voxel_size`` or ``glaze.voxel_size``) too fine for the
        extent of the ice.
    """
    g = np.asarray(gravity, dtype=np.float64).reshape(-1)
    if g.shape != (3,) or not np.isfinite(g).all() or not g.any():
        raise ValueError(f"gravity must be 3 finite numbers, not all zero; got {gravity!r}")
    nv = len(flow_mesh.vertices)
    for name in ("supply", "water", "d_up", "d_down"):
        if len(getattr(water, name)) != nv:
            raise ValueError(f"water.{name} has {len(getattr(water, name))} values for {nv} flow-mesh vertices")
    k = len(drips.positions)
    if not (len(drips.normals) == len(drips.water) == len(drips.faces) == k):
        raise ValueError("drips.positions, normals, water and faces differ in length")
    if len(drips.faces) and (np.min(drips.faces) < 0 or np.max(drips.faces) >= len(object_mesh.faces)):
        raise ValueError("drips.faces index faces outside object_mesh")
    off = np.asarray(trajectories.branch_offsets)
    if off.ndim != 1 or len(off) != trajectories.n_branches + 1 or (len(off) and off[-1] != len(trajectories.points)):
        raise ValueError("trajectories.branch_offsets must have n_branches + 1 entries ending at len(points)")
    if surface["mode"] == "tubes":
        verts, faces = tube_mesh(trajectories, surface, g)
        n_balls = 0
    else:
        voxel, coat_voxel = surface["voxel_size"], glaze["voxel_size"]
        ice = concat_balls(icicle_balls(trajectories, surface, rng), base_balls(object_mesh, drips, surface, rng))
        coarse = coat_voxel > voxel
        coat = glaze_balls(flow_mesh, water, glaze, rng, min_sheet=COAT_SHEET * coat_voxel if coarse else 0.0)
        verts, faces = ice_mesh(ice, coat, voxel, coat_voxel)
        n_balls = len(ice) + len(coat)
    tip_mm, ratios, wavelength = measure_icicles(verts, faces, trajectories, surface)
    return IceResult(verts, faces, tip_mm, ratios, wavelength, n_balls)
