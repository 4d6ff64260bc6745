"""Load any mesh (`icefarm.asset_io`), scale it to meters, clean it and report its problems."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh

from .asset_io import Asset, read_asset
from .errors import InputError
from .tol import tol


@dataclass(frozen=True)
class MeshProblems:
    """What stands in the way of water flowing along the mesh edges.

    Attributes
    ----------
    faces : int
        Face count after cleaning.
    components : int
        Connected pieces (face adjacency).
    boundary_edges : int
        Edges used by one face only (open boundaries).
    nonmanifold_edges : int
        Edges shared by more than two faces.
    self_intersections : int
        Faces that cross another face, or -1 when not measured.
    edge_fraction : float
        Median edge length over the bounding-box diagonal: how coarse the mesh is for its
        size (dense scans: under 0.01; a box-modelled table of a few dozen faces: 0.45).
    inside_out_faces : int
        Faces of pieces that came wound inside out (normals pointing in), turned outward by
        `orient_outward`.
    """

    faces: int
    components: int
    boundary_edges: int
    nonmanifold_edges: int
    self_intersections: int = -1
    edge_fraction: float = 0.0
    inside_out_faces: int = 0

    @property
    def watertight(self) -> bool:
        return self.boundary_edges == 0 and self.nonmanifold_edges == 0


@dataclass(frozen=True)
class PreparedMesh:
    """A cleaned mesh in meters, centred on the origin.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Welded, without degenerate faces, in meters.
    scale : float
        Meters per input unit.
    offset : (3,) float
        Subtracted from the scaled input vertices (the bounding-box centre), in meters.
    problems : MeshProblems
    """

    mesh: trimesh.Trimesh
    scale: float
    offset: np.ndarray
    problems: MeshProblems


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Read one mesh (OBJ, PLY, STL, OFF, GLB, USD, ...) as a single `trimesh.Trimesh`, in
    the file's units (`icefarm.asset_io.read_asset`: scenes and stages flattened with their
    transforms, a missing material file ignored, latin-1 text read).

    Raises
    ------
    InputError
        The file is missing, unreadable, holds no triangles, or has non-finite vertices.
    """
    asset = read_asset(path)
    return trimesh.Trimesh(asset.vertices, asset.faces, process=False)


def clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Weld duplicate vertices, drop degenerate and duplicate faces and unused vertices."""
    mesh = mesh.copy()
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces(height=tol.degenerate))
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


# A piece whose volume signed by its winding, about its centroid, is below this share of the
# same volume unsigned is wound inside out. Outward closed pieces give +1 (convex) to about
# +0.8 (a bunny, holes and all); sheets give about 0 and are left alone, as are pieces whose
# faces disagree (about 0 too).
INSIDE_OUT = -0.5


def orient_outward(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """``mesh`` with each piece that is wound inside out (its normals pointing in) turned
    outward, and how many faces turned.

    DCC exports come inside out now and then (a negative scale, a flipped-normals toggle);
    water and rain read the winding, and a 0.3 m bunny wound inside out catches no rain at all:
    no glaze, no icicles. trimesh's ``fix_inversion`` turns watertight pieces only; scans
    have holes. A piece's signed volume about its own centroid (`INSIDE_OUT`) tells without
    a closed surface. A piece within another's bounding box is left alone: the wall of a
    cavity faces into it.
    """
    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        return mesh, 0
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    tri = mesh.triangles
    area = mesh.area_faces
    pieces = int(labels.max()) + 1
    weight = np.maximum(np.bincount(labels, weights=area, minlength=pieces), 1e-300)
    centroid = np.column_stack([np.bincount(labels, weights=area * tri[:, :, k].mean(axis=1), minlength=pieces)
                                for k in range(3)]) / weight[:, None]
    rel = tri - centroid[labels][:, None, :]
    volume = np.einsum("ij,ij->i", np.cross(rel[:, 0], rel[:, 1]), rel[:, 2])  # 6 x each tetrahedron's
    signed = np.bincount(labels, weights=volume, minlength=pieces)
    unsigned = np.bincount(labels, weights=np.abs(volume), minlength=pieces)
    inside_out = np.flatnonzero(signed < INSIDE_OUT * unsigned)
    if len(inside_out):
        # A piece inside another's box is a cavity's wall, wound into the cavity on purpose
        # (a hollow ball's inner shell, a mug's separate inner wall): left as it is.
        order = np.argsort(labels, kind="stable")
        corners = tri[order].reshape(-1, 3)
        starts = np.r_[0, np.cumsum(np.bincount(labels, minlength=pieces))[:-1]] * 3
        lo, hi = np.minimum.reduceat(corners, starts), np.maximum.reduceat(corners, starts)
        size = np.prod(hi - lo, axis=1)
        nested = [bool(np.any((lo <= lo[i]).all(axis=1) & (hi >= hi[i]).all(axis=1) & (size > size[i])))
                  for i in inside_out]
        inside_out = inside_out[~np.asarray(nested, dtype=bool)]
    turn = np.isin(labels, inside_out)
    if not turn.any():
        return mesh, 0
    faces = faces.copy()
    faces[turn] = faces[turn][:, ::-1]
    return trimesh.Trimesh(mesh.vertices, faces, process=False), int(turn.sum())


def detect_problems(mesh: trimesh.Trimesh, self_intersections: bool = True) -> MeshProblems:
    """Measure loose pieces, open boundaries, non-manifold edges, crossing faces and coarseness.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        A welded mesh (see `clean`): unwelded seams count as open boundaries.
    self_intersections : bool
        Also count faces that cross another face (via pymeshlab, in time that grows with
        the faces);
        without it ``self_intersections`` is -1.
    """
    faces = len(mesh.faces)
    if faces == 0:
        return MeshProblems(faces=0, components=0, boundary_edges=0, nonmanifold_edges=0,
                            self_intersections=0 if self_intersections else -1)
    counts = np.bincount(mesh.edges_unique_inverse)  # faces on each edge
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=faces)
    crossings = count_self_intersections(mesh) if self_intersections else -1
    diagonal = float(np.linalg.norm(np.ptp(mesh.vertices[mesh.faces.ravel()], axis=0)))
    return MeshProblems(
        faces=faces,
        components=int(labels.max()) + 1,
        boundary_edges=int((counts == 1).sum()),
        nonmanifold_edges=int((counts > 2).sum()),
        self_intersections=crossings,
        edge_fraction=float(np.median(mesh.edges_unique_length)) / diagonal if diagonal > 0 else 0.0,
    )


def count_self_intersections(mesh: trimesh.Trimesh) -> int:
    """Faces of ``mesh`` that cross another face they share no vertex with (pymeshlab).

    Counts faces, not pairs: two crossing triangles count 2. Folds of clean meshes cross a
    few (cow.obj: 82 of 5,804); parts passing through each other cross many.
    """
    if len(mesh.faces) == 0:
        return 0
    from .meshlab import meshset

    ms = meshset(mesh)
    ms.compute_selection_by_self_intersections_per_face()
    return int(ms.current_mesh().selected_face_number())


# A mesh thinner than `tol.flat` of its diagonal is flat (a plane, a sign, a sheet, a
# single triangle): it gets FLAT_THICKNESS_M of thickness, so that the water that falls on
# it runs over its faces and round its rims as on any closed object.
FLAT_THICKNESS_M = 0.002  # a sheet of metal, a sign's board (at most FLAT_THICKNESS_RATIO of the diagonal)
FLAT_THICKNESS_RATIO = 0.01
# A mesh whose height along gravity is under this fraction of its largest extent lies flat:
# ``size_m`` is then its largest extent. A level sheet out of a DCC is level only to its float
# noise (1e-8 to 1e-5 of its size); scaling that noise to ``size_m`` would make a 1 m roof panel
# thousands of kilometres wide, which the proxy would then refuse or run out of memory on.
LEVEL_FRACTION = 1e-4


def prepare(path: str | Path | trimesh.Trimesh, size_m: float | None,
            gravity=(0.0, -1.0, 0.0)) -> PreparedMesh:
    """Load, scale and clean a mesh so its height along gravity is ``size_m`` meters, or
    keep the real size its file gives (USD, glTF) when ``size_m`` is None.

    The mesh is scaled before it is cleaned, so its units do not matter (welding and the
    test for degenerate faces work in meters: a model in nanometres is not one point).
    A flat mesh is given a thickness (`solidify`): a plane, a sign or a single triangle
    becomes a thin closed slab that water can run over. Pieces wound inside out are turned
    outward (`orient_outward`).

    Parameters
    ----------
    path : path or trimesh.Trimesh
        Any format `icefarm.asset_io.read_asset` reads, or a mesh already in memory.
    size_m : float or None
        Real height of the object's bounding box along gravity, in meters. Objects lying
        flat (height under `LEVEL_FRACTION` of their largest extent) take it as their
        largest extent instead. None: the file's own units (USD ``metersPerUnit``, glTF's
        meters); OBJ, PLY, STL, OFF and meshes in memory carry none and need it.
    gravity : (3,) float
        Direction of gravity.

    Raises
    ------
    InputError
        Bad file or mesh, a size that is not a positive number, or no size for a format
        without units.
    """
    if size_m is not None and (not np.isfinite(size_m) or size_m <= 0):
        raise InputError(f"size_m must be a positive number of meters, got {size_m!r}")
    if isinstance(path, trimesh.Trimesh):
        if len(path.faces) == 0 or not np.isfinite(path.vertices).all():
            raise InputError("the generated mesh is empty or has non-finite vertices")
        raw = Asset(np.asarray(path.vertices, dtype=np.float64), np.asarray(path.faces, dtype=np.int64))
        path = "(generated)"
    else:
        raw = read_asset(path)
    if size_m is None and raw.meters_per_unit is None:
        kind = Path(path).suffix.lstrip(".").upper() or "file"
        what = "a generated mesh" if path == "(generated)" else f"{path}: the {kind} format"
        raise InputError(f"{what} carries no units: pass the object's real height in meters with --size-m "
                         "(icefarm run) or size_m (manifest)")
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    if np.asarray(raw.faces).min() < 0 or np.asarray(raw.faces).max() >= len(raw.vertices):
        raise InputError(f"mesh {path} has faces that name vertices it does not have")
    # Scale on the vertices the faces use, then clean in meters; scale again for what cleaning removed.
    scale, centre = _fit(raw.vertices[np.unique(raw.faces)], size_m, g, path, raw.meters_per_unit)
    mesh = clean(trimesh.Trimesh(raw.vertices * scale - centre, raw.faces, process=False))
    if len(mesh.faces) == 0:
        raise InputError(f"mesh {path} has only degenerate faces")
    again, shift = _fit(mesh.vertices, size_m, g, path, 1.0)
    mesh.vertices = mesh.vertices * again - shift
    scale, centre = scale * again, centre * again + shift
    mesh, inside_out = orient_outward(mesh)
    if is_flat(mesh):
        mesh = solidify(mesh, min(FLAT_THICKNESS_M, FLAT_THICKNESS_RATIO * float(np.linalg.norm(mesh.extents))))
    problems = replace(detect_problems(mesh), inside_out_faces=inside_out)
    return PreparedMesh(mesh=mesh, scale=scale, offset=centre, problems=problems)


def _fit(vertices: np.ndarray, size_m: float | None, g: np.ndarray, path,
         meters_per_unit: float | None = None) -> tuple[float, np.ndarray]:
    """``scale, centre`` that bring ``vertices`` to ``size_m`` along ``g`` (or their largest
    extent when they lie flat across ``g``), or to meters by ``meters_per_unit`` when
    ``size_m`` is None, centred on the origin: ``v * scale - centre``."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    extent = float((hi - lo).max())
    if not extent > 0 or not np.isfinite(extent):
        raise InputError(f"mesh {path} has no extent: all its vertices coincide")
    if size_m is None:
        scale = float(meters_per_unit)
    else:
        heights = vertices @ g
        height = float(heights.max() - heights.min())
        scale = size_m / (height if height > LEVEL_FRACTION * extent else extent)
    return scale, (lo + hi) / 2 * scale


def _thin_axis(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """The unit direction along which ``mesh`` is thinnest, and its thickness there."""
    v = mesh.vertices - mesh.vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(v, full_matrices=False)
    normal = axes[-1] if len(axes) == 3 else np.cross(*axes[:2]) if len(axes) == 2 else np.array([0.0, 1.0, 0.0])
    normal = normal / np.linalg.norm(normal)
    return normal, float(np.ptp(v @ normal))


def is_flat(mesh: trimesh.Trimesh) -> bool:
    """All faces in one plane (to `tol.flat` of the diagonal): no volume, no inside."""
    diagonal = float(np.linalg.norm(mesh.extents))
    return diagonal > 0 and _thin_axis(mesh)[1] <= tol.flat * diagonal


def solidify(mesh: trimesh.Trimesh, thickness: float) -> trimesh.Trimesh:
    """A flat ``mesh`` as a closed slab ``thickness`` thick: its faces on both sides of its
    plane, joined along its open rims, every face pointing out."""
    normal, _ = _thin_axis(mesh)
    centre = mesh.vertices.mean(axis=0)
    flat = mesh.vertices - np.outer((mesh.vertices - centre) @ normal, normal)  # exactly in the plane
    faces = np.asarray(mesh.faces).copy()
    facing = np.cross(flat[faces[:, 1]] - flat[faces[:, 0]], flat[faces[:, 2]] - flat[faces[:, 0]]) @ normal
    faces[facing < 0] = faces[facing < 0][:, ::-1]  # all wound counter-clockwise seen from +normal
    n = len(flat)
    vertices = np.vstack([flat + normal * thickness / 2, flat - normal * thickness / 2])
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    rim = edges[counts[inverse.ravel()] == 1]  # open edges, in their face's winding
    a, b = rim[:, 0], rim[:, 1]
    sides = np.concatenate([np.column_stack([b, a, a + n]), np.column_stack([b, a + n, b + n])])
    out = trimesh.Trimesh(vertices, np.concatenate([faces, faces[:, ::-1] + n, sides]), process=False)
    out.merge_vertices()
    trimesh.repair.fix_normals(out)
    return out
