"""Ice at the base of each icicle (paper 4.4.3, Equation 2)."""

from __future__ import annotations

import math

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ...geometry import ragged_arange, random_barycentric, stable_order
from ...metaballs.balls import LEVEL, NO_BALLS, Balls
from ...params import SurfaceParams
from ...spatial import ray_caster
from ...tol import tol
from ..drips import DripResult

# Width over radius of a base ball: a lone ball's surface sits at its radius rb, and wide
# balls blend into one smooth swelling rather than a cluster of beads.
BASE_KAPPA = 1.0
# Most a base ball's radius may be, in radii of its icicle where it leaves the object.
BASE_SWELL = 0.7
# Base balls sit this many of their radii inside the object: what shows is a low lens
# hugging the surface (a fillet, as ice at real icicle roots), not a ball on it; a
# surface-centred cluster reads as a milky snowball at lookdev.
BASE_SINK = 0.5
# Candidate points drawn per drip point (at least; more for nmb over 60).
BASE_POOL = 256
# Most a base ball's radius may be, in thicknesses of the object under it (a ray cast
# against its face normal): sunk BASE_SINK of itself, it then reaches 0.9 of the way
# through and stands 0.3 of the thickness proud. A base hugs a thin rim (an eave's 1 cm
# slab) as a fillet instead of bulging past both of its faces as a glass knob.
BASE_THICKNESS = 0.6

def base_balls(object_mesh: trimesh.Trimesh, drips: DripResult, surface: SurfaceParams,
               rng: np.random.Generator, icicle_radius: np.ndarray | None = None, cast=None,
               gravity: np.ndarray | None = None) -> Balls:
    """``nmb`` balls on the object around each drip point (paper 4.4.3, Equation 2).

    Points are drawn area-weighted on the faces that come within ``eb`` (Euclidean) of the
    drip point and connect to the drip point's face through such faces (so no ice jumps
    to a nearby but separate part); each is a ball of radius ``rb = (eb - d)^2 / eb^2 *
    wc * kb`` (d: distance to the drip point, wc: its water coefficient). The balls add
    into one field, so where they crowd (near the drip point) the base swells past any
    one of them: more balls or a wider extent, more ice. Each drip's candidates come from a
    pool of a fixed size, so the balls of a smaller ``nmb`` are the first of a larger one's.

    ``icicle_radius`` (k,), meters: each icicle's radius where it leaves the object. A
    ball's radius is held to ``BASE_SWELL`` times it, so a drip with much water but a short
    icicle (one the ground stopped) grows a fillet, not a boulder. Balls sink
    ``BASE_SINK`` of their radius into the object along its face normal, and are held to
    ``BASE_THICKNESS`` times the object's thickness under them (`object_thickness`: a
    ray cast against the normal and, with ``gravity``, the height of the part there; ``cast``
    is an `icefarm.spatial.ray_caster` of ``object_mesh``, made here when not given), so a
    base is never thicker than the rim it sits on.
    """
    eb, nmb, kb = surface.base_extent, surface.base_balls, surface.base_scale
    k = len(drips.positions)
    if k == 0 or eb <= 0 or nmb == 0 or kb <= 0:
        return NO_BALLS
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
        return NO_BALLS

    # Draw a pool of points on each drip's faces by area, keep those within eb, take nmb.
    areas = object_mesh.area_faces[face]
    cum = np.cumsum(areas)
    first = np.searchsorted(drip, np.arange(k))
    last = np.searchsorted(drip, np.arange(k), side="right")
    has = last > first
    total = np.where(has, cum[np.maximum(last - 1, 0)] - np.where(first > 0, cum[np.maximum(first - 1, 0)], 0.0), 0.0)
    sd = np.repeat(np.flatnonzero(has & (total > 0)), max(BASE_POOL, 4 * nmb + 16))
    start = np.where(first > 0, cum[np.maximum(first - 1, 0)], 0.0)
    pick = np.searchsorted(cum, start[sd] + rng.random(len(sd)) * total[sd], side="right")
    pick = np.clip(pick, first[sd], last[sd] - 1)
    pts = trimesh.triangles.barycentric_to_points(tris[face[pick]], random_barycentric(len(pick), rng))
    normals = object_mesh.face_normals[face[pick]]
    d = np.linalg.norm(pts - pos[sd], axis=1)
    inside = d < eb
    sd, pts, d, normals = sd[inside], pts[inside], d[inside], normals[inside]
    rank = np.arange(len(sd)) - np.searchsorted(sd, sd)  # sd is sorted
    take = rank < nmb
    sd, pts, d, normals = sd[take], pts[take], d[take], normals[take]
    radius = (eb - d) ** 2 / eb**2 * np.asarray(drips.water, dtype=np.float64)[sd] * kb
    if icicle_radius is not None:
        radius = np.minimum(radius, BASE_SWELL * np.asarray(icicle_radius, dtype=np.float64)[sd])
    if len(pts):
        radius = np.minimum(radius, BASE_THICKNESS * object_thickness(object_mesh, pts, normals, cast, gravity))
    keep = radius > 0
    if not keep.any():
        return NO_BALLS
    pts = pts - (BASE_SINK * radius)[:, None] * normals
    widths = BASE_KAPPA * radius[keep]
    return Balls(pts[keep], widths, np.full(len(widths), LEVEL * math.exp(1.0 / BASE_KAPPA**2)))


def object_thickness(mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray, cast=None,
                     gravity: np.ndarray | None = None) -> np.ndarray:
    """(k,) thickness of ``mesh`` at surface ``points`` (k, 3), meters: how far a ray cast
    from each against its outward unit normal runs inside before leaving; with ``gravity``
    (3,), at most the part's height there (rays up and down from just inside), which is
    what a point on the end face of a thin slab has (inf where rays never leave: an open
    mesh)."""
    if cast is None:
        cast = ray_caster(mesh)
    nudge = tol.inset * float(np.ptp(mesh.vertices, axis=0).max())
    start = points - nudge * normals
    thickness, _ = cast(start, -normals)
    thickness = thickness + nudge
    if gravity is not None:
        down = np.broadcast_to(np.asarray(gravity, dtype=np.float64) / np.linalg.norm(gravity), points.shape)
        height = cast(start, down)[0] + cast(start, -down)[0]
        thickness = np.minimum(thickness, height)
    return thickness


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
    order = stable_order(np.r_[adj[:, 0], adj[:, 1]])
    nbr = np.r_[adj[:, 1], adj[:, 0]][order]
    nbr_start = np.searchsorted(np.r_[adj[:, 0], adj[:, 1]][order], np.arange(n_faces + 1))
    while len(frontier):
        f = face[frontier]
        cnt = nbr_start[f + 1] - nbr_start[f]
        src = np.repeat(frontier, cnt)
        off = ragged_arange(cnt)
        cand = drip[src] * n_faces + nbr[nbr_start[face[src]] + off]
        i = np.minimum(np.searchsorted(key, cand), len(key) - 1)
        new = np.zeros(len(key), dtype=bool)
        new[i[key[i] == cand]] = True
        new &= ~reached
        reached |= new
        frontier = np.flatnonzero(new)
    return drip[reached], face[reached]
