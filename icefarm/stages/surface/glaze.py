"""Glaze ice over the wet surface (paper 4.4.4, Equation 3)."""

from __future__ import annotations

import numpy as np
import trimesh

from ...metaballs.balls import NO_BALLS, Balls, sheet_balls
from ..water import WaterResult
from .bases import _random_barycentric

# With the glaze on its own coarser lattice, its sheet is at least this many glaze voxels
# thick (the extra thickness goes inside the object), so marching cubes tears it less.
COAT_SHEET = 2.0


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
        return NO_BALLS
    wet = np.asarray(water.supply, dtype=bool) | (np.asarray(water.water) > 0)
    faces = flow_mesh.faces
    wet_faces = np.flatnonzero(wet[faces].sum(axis=1) >= 2)
    areas = flow_mesh.area_faces[wet_faces]
    if len(wet_faces) == 0 or areas.sum() <= 0:
        return NO_BALLS
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
