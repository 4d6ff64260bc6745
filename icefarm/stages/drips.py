"""Stage 2 (paper 4.2): the drip region and the drip points on it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry import inside, ray_caster, sample_faces, unit


@dataclass(frozen=True)
class DripResult:
    """Where the water drips.

    Attributes
    ----------
    region_faces : (m,) int
        Faces of the drip region.
    positions : (k, 3) float
        Drip points, in meters.
    normals : (k, 3) float
        Unit surface normals at the drip points (interpolated vertex normals).
    water : (k,) float
        Water coefficient interpolated at each drip point, in meters.
    faces : (k,) int
        Face holding each drip point.
    """

    region_faces: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    water: np.ndarray
    faces: np.ndarray


def drip_criterion(normals: np.ndarray, gravity: np.ndarray, drip_limit: float) -> np.ndarray:
    """``(n,) bool``: each unit normal ``(n, 3)`` lies within ``drip_limit`` degrees of gravity."""
    return normals @ unit(gravity) >= np.cos(np.radians(drip_limit))


def excluded_vertices(vertices: np.ndarray, boxes=()) -> np.ndarray:
    """``(n,) bool``: vertices inside any box ``((xmin, ymin, zmin), (xmax, ymax, zmax))``."""
    inside = np.zeros(len(vertices), dtype=bool)
    for lo, hi in boxes:
        inside |= np.all((vertices >= np.asarray(lo)) & (vertices <= np.asarray(hi)), axis=1)
    return inside


def drip_region(mesh: trimesh.Trimesh, water: np.ndarray, gravity, drip_limit: float,
                excluded: np.ndarray | None = None) -> np.ndarray:
    """Faces with a wet vertex whose vertex normals all meet the drip criterion.

    Parameters
    ----------
    water : (n,) float
        Water coefficient per vertex.
    excluded : (n,) bool, optional
        Vertices where no icicle may hang; faces touching them leave the region.

    Returns
    -------
    (m,) int
        Face indices of the drip region.
    """
    ok = drip_criterion(mesh.vertex_normals, gravity, drip_limit)
    if excluded is not None:
        ok &= ~excluded
    faces = mesh.faces
    region = ok[faces].all(axis=1) & (water[faces] > 0).any(axis=1)
    return np.flatnonzero(region)


def _transition_points(mesh: trimesh.Trimesh, water: np.ndarray, ok: np.ndarray, count: int,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Drip points on edges and vertices that meet the criterion where no whole face does.

    Coarse, highly curved meshes (paper 4.2) can meet the criterion at a vertex or along
    an edge while no face meets it at all three vertices.

    Returns
    -------
    corners : (k, 3) int
        Vertices each point interpolates.
    weights : (k, 3) float
        Their weights (the third is 0 on an edge; a vertex gets weight 1).
    """
    edges = mesh.edges_unique
    good = ok[edges].all(axis=1) & (water[edges] > 0).any(axis=1)
    edges, lengths = edges[good], mesh.edges_unique_length[good]
    if lengths.sum() > 0:
        ends = edges[rng.choice(len(edges), size=count, p=lengths / lengths.sum())]
        s = rng.random(count)
        return np.column_stack([ends, ends[:, 0]]), np.column_stack([1 - s, s, np.zeros(count)])
    candidates = np.flatnonzero(ok & (water > 0))
    chosen = rng.choice(candidates, size=min(count, len(candidates)), replace=False)
    return np.repeat(chosen[:, None], 3, axis=1), np.tile([1.0, 0.0, 0.0], (len(chosen), 1))


def find_drips(mesh: trimesh.Trimesh, water: np.ndarray, gravity, count: int, drip_limit: float,
               rng: np.random.Generator, exclude_boxes=(),
               exclude_vertices: np.ndarray | None = None, caster=None) -> DripResult:
    """Stage 2: the drip region and ``count`` random drip points on it.

    Points are spread area-weighted over the region's faces. Where no face qualifies
    (coarse curved meshes) they go on the qualifying edges, length-weighted, or vertices.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface stage 1 ran on, in meters.
    water : (n,) float
        Water coefficients of its vertices.
    gravity : (3,) float
    count : int
        Drip points wanted (ns); fewer come back only when the region has fewer vertices.
    drip_limit : float
        dl, degrees from gravity.
    rng : numpy.random.Generator
    exclude_boxes : sequence of ((3,), (3,)) corners, meters
        No icicles on faces touching a vertex inside a box.
    exclude_vertices : (n,) bool, optional
        No icicles on faces touching these vertices (a painted mask).
    caster : callable, optional
        A `icefarm.geometry.ray_caster` of ``mesh`` to reuse.
    """
    water = np.asarray(water, dtype=np.float64)
    if water.shape != (len(mesh.vertices),):
        raise ValueError(f"water must have one value per vertex ({len(mesh.vertices)}), got {water.shape}")
    if not 0 < drip_limit < 90:
        raise ValueError(f"drip_limit must lie in ]0, 90[ degrees, got {drip_limit}")
    excluded = excluded_vertices(mesh.vertices, exclude_boxes)
    if exclude_vertices is not None:
        excluded |= np.asarray(exclude_vertices, dtype=bool)
    region = drip_region(mesh, water, gravity, drip_limit, excluded)
    points, face, bary = sample_faces(mesh, region, 2 * count, rng)
    if len(face) and mesh.is_watertight:
        # Faces buried inside another part (a horn through a head) cannot drip.
        lifted = points + 1e-4 * float(np.linalg.norm(mesh.extents)) * mesh.face_normals[face]
        free = ~inside(caster or ray_caster(mesh), lifted)
        face, bary = face[free], bary[free]
    face, bary = face[:count], bary[:count]
    corners = mesh.faces[face]
    if len(face) == 0 and count > 0:
        ok = drip_criterion(mesh.vertex_normals, gravity, drip_limit) & ~excluded
        corners, bary = _transition_points(mesh, water, ok, count, rng)
        face = mesh.vertex_faces[corners[:, 0], 0]
    positions = np.einsum("ij,ijk->ik", bary, mesh.vertices[corners])
    normals = unit(np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[corners]))
    return DripResult(region_faces=region, positions=positions, normals=normals,
                      water=np.einsum("ij,ij->i", bary, water[corners]), faces=face)
