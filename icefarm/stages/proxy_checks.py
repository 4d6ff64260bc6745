"""What makes a mesh need an approximate surface (`icefarm.stages.proxy`) and moving points
from that surface back onto the object.

`proxy_reason` says why stages 1-2 cannot run on a mesh as it is (loose or intersecting
pieces, open boundaries, non-manifold edges, too many faces, too few for its size); the
phrases and tests it uses also choose how `icefarm.stages.proxy.build_proxy` builds one.
Drip points found on the proxy are moved back onto the real mesh with `snap_to_surface`,
so the icicles hang from the object itself.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ..errors import InputError
from ..mesh import MeshProblems
from ..spatial import closest_point
from ..tol import tol

# Folds of otherwise clean meshes cross a few faces (cow.obj: 1.4 %, dragon: 0.02 %)
# without hurting a flow along edges; parts passing through each other cross many more.
SELF_INTERSECTING_FRACTION = 0.05
# A mesh whose median edge is longer than this fraction of its diagonal is too coarse to
# carry the flow (a box-modelled table: 0.45, a 10-sided cylinder: 0.24, an 80-face
# icosphere: 0.17; the generators at their default detail: 0.02-0.03, the shared scans
# under 0.025).
COARSE_EDGE_FRACTION = 0.1


def problem_phrases(problems: MeshProblems) -> list[str]:
    """What breaks the flow along edges, one phrase per problem found."""
    phrases = []
    if problems.components > 1:
        phrases.append(f"{problems.components} loose components")
    if problems.boundary_edges > 0:
        phrases.append(f"{problems.boundary_edges} open boundary edges")
    if problems.nonmanifold_edges > 0:
        phrases.append(f"{problems.nonmanifold_edges} non-manifold edges")
    if problems.self_intersections > SELF_INTERSECTING_FRACTION * problems.faces:
        phrases.append(f"{problems.self_intersections} self-intersecting faces")
    return phrases


def is_coarse(problems: MeshProblems) -> bool:
    """Too few faces for its size: the median edge is over `COARSE_EDGE_FRACTION` of the diagonal."""
    return problems.edge_fraction > COARSE_EDGE_FRACTION


def proxy_reason(problems: MeshProblems, mode: str, face_budget: int) -> str | None:
    """Why stages 1-2 need an approximate surface, or None when the mesh itself will do.

    Parameters
    ----------
    problems : MeshProblems
        From `icefarm.mesh.detect_problems` (self-intersections count only when measured,
        and only above `SELF_INTERSECTING_FRACTION` of the faces).
    mode : {"auto", "always", "never"}
        ``proxy.mode``: ``auto`` builds one for problem meshes, ``always`` for every mesh,
        ``never`` for none.
    face_budget : int
        ``proxy.face_budget``: more faces than this is a reason in itself.

    A coarse mesh (`COARSE_EDGE_FRACTION`) is a reason too: its flow runs on a refined copy.

    Returns
    -------
    str or None
        For example ``"6 loose components, 51 non-manifold edges"``.
    """
    if mode == "never":
        return None
    phrases = problem_phrases(problems)
    if problems.faces > face_budget:
        phrases.append(f"{problems.faces} faces over the budget of {face_budget}")
    if is_coarse(problems):
        phrases.append(f"coarse: {problems.faces} faces, median edge {problems.edge_fraction:.2f} "
                       "of the diagonal")
    if phrases:
        return ", ".join(phrases)
    return "proxy.mode is always" if mode == "always" else None


def only_holes(problems: MeshProblems) -> bool:
    """One manifold piece whose only flaw is open boundaries."""
    return (problems.boundary_edges > 0 and problems.components == 1 and problems.nonmanifold_edges == 0
            and problems.self_intersections <= SELF_INTERSECTING_FRACTION * problems.faces)


def boundary_loops(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices on open boundaries and the loop each belongs to.

    Returns
    -------
    vertices : (b,) int
        Vertices used by an edge of one face only.
    loops : (b,) int
        Loop label of each, ``0 .. n_loops - 1`` (loops touching at a vertex count as one).
    """
    edges = mesh.edges_sorted
    boundary = edges[trimesh.grouping.group_rows(edges, require_count=1)]
    vertices = np.unique(boundary)
    if len(vertices) == 0:
        return vertices, vertices.copy()
    local = np.searchsorted(vertices, boundary)
    return vertices, trimesh.graph.connected_component_labels(local, node_count=len(vertices))


def _thickness(vertices: np.ndarray) -> float:
    """Extent of ``vertices`` ``(n, 3)`` along their least principal axis, in their units."""
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    along = centred @ axes[-1]
    return float(along.max() - along.min())


def solid_diagonal(mesh: trimesh.Trimesh) -> float:
    """Bounding-box diagonal of the faces' vertices, in meters; InputError when the mesh is flat."""
    used = np.asarray(mesh.vertices, dtype=np.float64)[np.unique(mesh.faces)]
    diag = float(np.linalg.norm(np.ptp(used, axis=0)))
    thickness = _thickness(used)
    if diag <= 0 or thickness <= tol.flat * diag:
        raise InputError(
            f"the mesh is flat (thickness {thickness:.3g} m over a {diag:.3g} m diagonal): it has "
            "no volume to wrap an approximate surface around; set proxy.mode: never to let the "
            "water run on the mesh as it is")
    return diag


def snap_to_surface(points: np.ndarray, mesh: trimesh.Trimesh,
                    reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move points to the closest point of ``mesh`` (drip points from the proxy to the object).

    Parameters
    ----------
    points : (k, 3) float
        Points near the surface, in meters.
    mesh : trimesh.Trimesh
        The real object, in meters; it need not be watertight or consistently oriented.
    reference : (k, 3) float, optional
        Outward normals at ``points`` (the proxy's, which is closed and wound outward).

    Returns
    -------
    closest : (k, 3) float
        Closest points on ``mesh``.
    normals : (k, 3) float
        Unit normals of the faces there, turned to agree with ``reference``; without one,
        towards the side each point came from (outward where the proxy lies outside the
        object, as a wrap does, even on soups with random winding), and a point on the
        surface (within `tol.on_surface` of the diagonal) keeps its face's own normal. A
        decimated proxy lies on both sides of the object: on a 1.1 M-face scan of the bunny,
        the side a point came from turns 25 of 28 drip normals inwards and their icicles
        never grow.
    faces : (k,) int
        Face holding each closest point.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be shaped (k, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points must be finite")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("snap_to_surface needs a mesh with faces")
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    closest, distance, faces = closest_point(mesh, points)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[faces]
    if reference is not None:
        agree = np.einsum("ij,ij->i", normals, np.asarray(reference, dtype=np.float64).reshape(-1, 3))
        return np.asarray(closest, dtype=np.float64), np.where((agree < 0)[:, None], -normals, normals), faces
    facing = np.einsum("ij,ij->i", normals, points - closest)
    # Below this distance the side is rounding noise: the point is on the surface.
    on_surface = distance <= tol.on_surface * float(np.linalg.norm(mesh.extents))
    normals = np.where(((facing < 0) & ~on_surface)[:, None], -normals, normals)
    return np.asarray(closest, dtype=np.float64), normals, faces
