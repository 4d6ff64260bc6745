"""The approximate surface the water flows on when the real mesh cannot carry it (paper 5.1).

The paper's water flows along mesh edges, so loose or intersecting pieces, holes and
non-manifold edges break it, and superfluous detail makes it slow and noisy. For such
meshes stages 1-2 run on a proxy built with pymeshlab:

* one clean piece whose only flaw is a few small holes (a scan's base) gets them filled
  (`meshing_close_holes`);
* other broken meshes (soups, loose or intersecting parts, wide openings, non-manifold
  edges), and every mesh under ``proxy.mode: always``, are alpha-wrapped
  (`generate_alpha_wrap`: watertight, outward-oriented shells that bridge gaps narrower
  than alpha; screened Poisson kept the soups' interior walls), then remeshed
  isotropically (`meshing_isotropic_explicit_remeshing`) to an edge length suited to the
  flow;
* clean meshes that are only too detailed are decimated
  (`meshing_decimation_quadric_edge_collapse`) to the face budget;
* clean meshes that are too coarse for their size (box-modelled assets of a few dozen
  faces: a table, a sign, a low-poly cylinder) are refined: remeshed isotropically, creases
  kept, down to the size of their finest features (`FEATURE_PERCENTILE`), never finer
  than the flow's edge length. Their few vertices average their normals across sharp
  edges, so no face meets the drip criterion, and their few edges leave the water nowhere
  to go; the refined surface has crisp faces beside every crease and edges the walks can
  follow. Closed pieces that pass through each other (boxes stacked into a table) are
  refined as they are: water runs on each, and faces buried in another piece drip
  nowhere. Open coarse meshes are wrapped and remeshed to the same edge.

Lengths are fractions of a bounding-box diagonal: of each part's own where parts lie far
apart (`icefarm.stages.parts`), each built as it would be alone. Over the whole mesh's, two
30 cm cubes 300 m apart would each be wrapped into a 1.5 m blob that grows 30 icicles, where a
cube alone grows none.

Drip points found on the proxy are moved back onto the real mesh with `snap_to_surface`,
so the icicles hang from the object itself.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import InputError
from ..geometry import closest_point, signed_volume
from ..mesh import MeshProblems, detect_problems
from ..meshlab import current, meshset
from ..params import ProxyParams
from ..tol import tol
from .parts import group_pieces, piece_boxes

# Folds of otherwise clean meshes cross a few faces (cow.obj: 1.4 %, dragon: 0.02 %)
# without hurting a flow along edges; parts passing through each other cross many more.
SELF_INTERSECTING_FRACTION = 0.05
# The wrap has about WRAP_FACE_FACTOR * area / alpha**2 faces (measured 1.3-2.4 on the
# shared meshes); its time and memory grow with that count (memory: about 1.2 kB a face),
# so it is held under the face budget (finer would be remeshed away anyway) and
# MAX_WRAP_FACES by raising alpha, up to MAX_ALPHA of the diagonal.
WRAP_FACE_FACTOR = 2.0
MAX_WRAP_FACES = 1_000_000
MAX_ALPHA = 0.1
# Holes are filled only when each boundary loop spans at most this fraction of the
# diagonal (the bunny's base: 0.18); a wider opening (a bowl's rim) is wrapped instead.
HOLE_FRACTION = 0.25
# Isotropic remeshing: passes, and the area of an equilateral triangle of unit edge.
REMESH_ITERATIONS = 3
UNIT_TRIANGLE_AREA = np.sqrt(3.0) / 4.0
# A manifold piece with more than this many times proxy.face_budget faces (a scan) is first
# thinned out to that many by fast quadric simplification: on a 1.1 M-face scan of the bunny
# the rough cut to 240 k costs under a tenth of pymeshlab's hole filling and topology-keeping
# decimation on the full mesh, and leaves holes holes and edges manifold.
PRE_DECIMATE = 4
# Remeshing overshoots its area estimate by up to ~15 %: aim below the budget.
BUDGET_MARGIN = 0.8
# A mesh whose median edge is longer than this fraction of its diagonal is too coarse to
# carry the flow (a box-modelled table: 0.45, a 10-sided cylinder: 0.24, an 80-face
# icosphere: 0.17; the generators at their default detail: 0.02-0.03, the shared scans
# under 0.025).
COARSE_EDGE_FRACTION = 0.1
# A coarse mesh is refined down to its own finest features (this percentile of its edge
# lengths: a table top's thickness), not finer: Algorithm 1 counts an edge with one wet
# end at half its height, so splitting a slab's side into rows starves its rim of the
# water that runs over it (a 5 cm top split at 1.6 cm: 0.4 cm icicles; kept whole: 2.8 cm).
FEATURE_PERCENTILE = 10
# Parts far apart (`icefarm.stages.parts`) are built one by one, each at its own scale: a
# part's wrap, refinement or hole filling as it would be alone, with a share of
# proxy.face_budget by area, at least MIN_PART_FACES (the parameter's own floor). Past
# MAX_PARTS (a scatter of pebbles: the time grows with the parts) they are built together,
# at the whole mesh's scale.
MAX_PARTS = 256
MIN_PART_FACES = 100


class ProxyMethod(enum.Enum):
    """How the proxy was made."""

    WRAP = "alpha wrap + isotropic remesh"
    FILL = "hole filling"
    DECIMATE = "quadric decimation"
    REFINE = "isotropic refinement"
    AS_IS = "kept as it is"  # a part with nothing wrong, far from parts that needed a proxy


@dataclass(frozen=True)
class ProxyResult:
    """The approximate surface stages 1-2 run on.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Watertight proxy, in meters, in the frame of the input mesh.
    reason : str
        Why it was built (the problems found), plus any adjustment made to fit the budget.
    faces : int
        Faces of the proxy.
    components : int
        Connected pieces of the proxy (genuinely separate objects stay separate).
    seconds : float
        Wall time of the build.
    method : ProxyMethod
        Wrap, hole filling, decimation or refinement (all but decimation are followed by
        decimation when over the budget).
    alpha : float
        Alpha the wrap used, in meters (0 when not wrapped; the largest of the parts'): the
        proxy bridges gaps about this wide, so it lies up to about alpha from the object.
    parts : int
        Parts far apart built one by one, each at its own scale (1: built whole).
    """

    mesh: trimesh.Trimesh
    reason: str
    faces: int
    components: int
    seconds: float
    method: ProxyMethod
    alpha: float = 0.0
    parts: int = 1


def _problem_phrases(problems: MeshProblems) -> list[str]:
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


def _coarse(problems: MeshProblems) -> bool:
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
    phrases = _problem_phrases(problems)
    if problems.faces > face_budget:
        phrases.append(f"{problems.faces} faces over the budget of {face_budget}")
    if _coarse(problems):
        phrases.append(f"coarse: {problems.faces} faces, median edge {problems.edge_fraction:.2f} "
                       "of the diagonal")
    if phrases:
        return ", ".join(phrases)
    return "proxy.mode is always" if mode == "always" else None


def _thickness(vertices: np.ndarray) -> float:
    """Extent of ``vertices`` ``(n, 3)`` along their least principal axis, in their units."""
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    along = centred @ axes[-1]
    return float(along.max() - along.min())


def _component_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """``(n_faces,) int``: connected piece (shared edges) of each face."""
    return trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))


def drop_voids(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Drop closed pieces of negative signed volume: cavities sealed inside the wrap.

    A wrap of crossing sheets encloses empty pockets; their inward-facing shells lie
    inside the object, where no rain reaches, so they only add faces.
    """
    labels = _component_labels(mesh)
    keep = signed_volume(mesh.vertices, mesh.faces, labels=labels)[labels] > 0
    if keep.all():
        return mesh
    out = mesh.copy()
    out.update_faces(keep)
    out.remove_unreferenced_vertices()
    return out


def _run_filter(ms, name: str, **kwargs) -> None:
    import pymeshlab

    try:
        getattr(ms, name)(**kwargs)
    except pymeshlab.PyMeshLabException as exc:
        raise InputError(f"pymeshlab {name} failed on this mesh ({exc}); "
                         "set proxy.mode: never to run the water on the mesh as it is") from None


def _remesh(mesh: trimesh.Trimesh, edge: float, tolerance: float,
            iterations: int = REMESH_ITERATIONS) -> trimesh.Trimesh:
    """Isotropic remesh to edges of ``edge`` m, staying within ``tolerance`` m of ``mesh``."""
    import pymeshlab

    ms = meshset(mesh)
    _run_filter(ms, "meshing_isotropic_explicit_remeshing", iterations=int(iterations),
                targetlen=pymeshlab.PureValue(edge), featuredeg=30.0, checksurfdist=True,
                maxsurfdist=pymeshlab.PureValue(tolerance))
    return current(ms)


def _refine(mesh: trimesh.Trimesh, edge: float, tolerance: float) -> trimesh.Trimesh | None:
    """A coarse mesh remeshed to edges of about ``edge`` m, creases over 30 degrees kept.

    Each pass splits a long edge once, so the passes grow with how many times the longest
    edge must be halved. None when the result is not watertight.
    """
    longest = float(mesh.edges_unique_length.max())
    passes = REMESH_ITERATIONS + max(0, int(np.ceil(np.log2(max(longest / edge, 1.0)))))
    out = _remesh(mesh, edge, tolerance, iterations=passes)
    return out if out.is_watertight and len(out.faces) else None


def _thin_out(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """``mesh`` brought down to about ``faces`` faces by fast quadric simplification
    (`fast_simplification`), or as it is when it has no more than that: a first, rough pass
    over a scan of millions of faces before pymeshlab's careful ones (`PRE_DECIMATE`)."""
    if len(mesh.faces) <= faces:
        return mesh
    import fast_simplification

    vertices, tris = fast_simplification.simplify(np.asarray(mesh.vertices, dtype=np.float32),
                                                  np.asarray(mesh.faces, dtype=np.int32), target_count=int(faces))
    return trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(tris, dtype=np.int64), process=False)


def _decimate(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """Quadric edge collapse down to ``faces`` faces, keeping the topology."""
    ms = meshset(mesh)
    _run_filter(ms, "meshing_decimation_quadric_edge_collapse", targetfacenum=int(faces),
                preservetopology=True, preserveboundary=True, optimalplacement=True,
                planarquadric=True, autoclean=True)
    return current(ms)


def _wrap(mesh: trimesh.Trimesh, alpha: float, offset: float) -> trimesh.Trimesh:
    """Alpha wrap with ``alpha`` and ``offset`` in meters, sealed cavities removed."""
    import pymeshlab

    ms = meshset(mesh)
    # Welding vertices closer than a quarter of the offset drops slivers the wrap cannot
    # resolve anyway: chair_model.obj loses 11 % of its faces and 14 % of the wrap's time
    # (half the offset saves 23 % but lets the proxy stray 1.0 % of the diagonal).
    _run_filter(ms, "meshing_merge_close_vertices", threshold=pymeshlab.PureValue(0.25 * offset))
    _run_filter(ms, "meshing_remove_null_faces")
    # PureValue: absolute lengths; PercentageValue would be percent of pymeshlab's own bbox.
    _run_filter(ms, "generate_alpha_wrap", alpha=pymeshlab.PureValue(alpha),
                offset=pymeshlab.PureValue(offset))
    return drop_voids(current(ms))


def _edge_for_budget(area: float, edge: float, budget: int) -> float:
    """Edge length ``>= edge`` whose isotropic triangulation of ``area`` m^2 fits ``budget`` faces."""
    return max(edge, float(np.sqrt(area / (UNIT_TRIANGLE_AREA * BUDGET_MARGIN * budget))))


def _only_holes(problems: MeshProblems) -> bool:
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


def _fill_small_holes(mesh: trimesh.Trimesh, diag: float) -> trimesh.Trimesh | None:
    """``mesh`` with its holes filled, or None when a hole is too wide or filling leaves flaws."""
    vertices, loops = boundary_loops(mesh)
    order = np.argsort(loops, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(loops[order]) > 0])
    points = np.asarray(mesh.vertices)[vertices[order]]
    spans = np.linalg.norm(np.maximum.reduceat(points, starts) - np.minimum.reduceat(points, starts), axis=1)
    if spans.max() > HOLE_FRACTION * diag:
        return None
    ms = meshset(mesh)
    sizes = np.diff(np.r_[starts, len(order)])
    _run_filter(ms, "meshing_close_holes", maxholesize=int(sizes.max()) + 1, newfaceselected=False,
                selfintersection=False)
    filled = current(ms)
    return None if _problem_phrases(detect_problems(filled, self_intersections=True)) else filled


def _solid_diagonal(mesh: trimesh.Trimesh) -> float:
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


def build_proxy(mesh: trimesh.Trimesh, proxy: ProxyParams,
                problems: MeshProblems | None = None) -> ProxyResult:
    """Build the approximate surface stages 1-2 run on.

    Parts far apart (`icefarm.stages.parts`: two cubes metres apart) are built one by one,
    each as it would be alone (a clean part kept as it is), at its own scale and with its
    share of the face budget by area, and put together; a mesh of one part (the teapot, the
    bunny) is built whole.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The prepared object, in meters.
    proxy : ProxyParams
        The ``proxy`` group of the resolved parameters: ``face_budget`` (faces), ``alpha``, ``offset`` and
        ``edge_length`` (fractions of each part's bounding-box diagonal). Whether to build one at
        all is the caller's call (`proxy_reason`); ``mode: always`` wraps even a clean mesh.
    problems : MeshProblems, optional
        ``detect_problems(mesh)`` when the caller has it; measured here otherwise.

    Returns
    -------
    ProxyResult
        Watertight, at most ``face_budget`` faces, in the frame of ``mesh``.

    Raises
    ------
    InputError
        Bad parameters; a mesh with no volume (flat or a single triangle), which has
        nothing to wrap; a surface so large for its size that the wrap would need an alpha
        over `MAX_ALPHA` of the diagonal to stay within the face budget.
    """
    start = time.perf_counter()
    budget = proxy.face_budget
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError("the mesh has no faces to build an approximate surface from")
    if not np.isfinite(np.asarray(mesh.vertices, dtype=np.float64)).all():
        raise InputError("the mesh has NaN or infinite vertex coordinates")
    diag = _solid_diagonal(mesh)
    if problems is None:
        problems = detect_problems(mesh, self_intersections=True)
    parts, count = None, 1
    if problems.components > 1:
        pieces = _component_labels(mesh)
        parts = group_pieces(*piece_boxes(mesh.vertices, mesh.faces, pieces), gap=proxy.alpha)[pieces]
        count = int(parts.max()) + 1
    built, together = None, None
    if count > MAX_PARTS:
        together = f"{count} parts far apart (over {MAX_PARTS}) built together"
    elif count > 1:
        try:
            built = _build_parts(mesh, parts, proxy)
        except InputError as exc:  # a flat part (a sheet), which the whole's wrap thickens
            together = f"{count} parts far apart built together (one alone: {str(exc).split(';')[0]})"
    if built is None:
        built = _build(mesh, proxy, problems, budget, diag)
        if together:
            built = dataclasses.replace(built, notes=[together, *built.notes])
    out, method, notes = built.mesh, built.method, list(built.notes)
    if len(out.faces) > budget:
        if method is not ProxyMethod.DECIMATE:
            notes.append(f"{method.value} gave {len(out.faces)} faces, decimated to the budget")
        out = _decimate(out, budget)
    out = trimesh.Trimesh(out.vertices, out.faces, process=True)
    if not out.is_watertight:
        raise InputError(f"the approximate surface ({method.value}) is not watertight; "
                         "set proxy.mode: never, or repair the mesh")
    trimesh.repair.fix_inversion(out, multibody=True)  # wound outward: the water and the drips' normals read it
    reason = proxy_reason(problems, "always", budget)
    if notes:
        reason = f"{reason}; {'; '.join(notes)}"
    components = int(_component_labels(out).max()) + 1
    return ProxyResult(mesh=out, reason=reason, faces=len(out.faces), components=components,
                       seconds=time.perf_counter() - start, method=method, alpha=built.alpha,
                       parts=built.parts)


@dataclass(frozen=True)
class _Built:
    """A proxy before its last checks: the surface, how it was made, the wrap's alpha in
    meters (the largest of the parts'), notes on adjustments, and the parts built apart."""

    mesh: trimesh.Trimesh
    method: ProxyMethod
    alpha: float
    notes: list[str]
    parts: int = 1


def _build_parts(mesh: trimesh.Trimesh, parts: np.ndarray, proxy: ProxyParams) -> _Built:
    """Each part (``parts``, ``(n_faces,) int``) built as it would be alone, put together.

    A part is kept as it is where `proxy_reason` finds nothing wrong with it (an intact
    cube beside a broken one), and built with `_build` otherwise. The face budget is shared
    by area, a part getting at least what its wrap needs to stay under `MAX_ALPHA` of its
    own diagonal (`MIN_PART_FACES` at least).
    """
    vertices, faces = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    areas = np.bincount(parts, weights=mesh.area_faces)
    pieces, methods, notes, alpha = [], [], [], 0.0
    for label, area in enumerate(areas):
        part = trimesh.Trimesh(vertices, faces[parts == label], process=False)
        part.remove_unreferenced_vertices()
        # Built about its own centre, as it would be alone (`icefarm.mesh.prepare` centres
        # the box): the remeshing follows the coordinates' last bits (a table 15 m off the
        # origin got another top; centred, its top is the lone table's, its legs 90 faces
        # where the lone table's have 104-118).
        centre = part.bounds.mean(axis=0)
        part.apply_translation(-centre)
        diag = _solid_diagonal(part)
        least = WRAP_FACE_FACTOR * area / (MAX_ALPHA * diag) ** 2
        budget = int(max(MIN_PART_FACES, np.ceil(least), proxy.face_budget * area / areas.sum()))
        problems = detect_problems(part, self_intersections=True)
        if proxy_reason(problems, proxy.mode, budget) is None:
            pieces.append(part.apply_translation(centre))
            methods.append(ProxyMethod.AS_IS)
            continue
        built = _build(part, proxy, problems, budget, diag)
        out = built.mesh
        if len(out.faces) > budget:
            if built.method is not ProxyMethod.DECIMATE:
                built.notes.append(f"{built.method.value} gave {len(out.faces)} faces, decimated to "
                                   f"its {budget}")
            out = _decimate(out, budget)
        pieces.append(out.apply_translation(centre))
        methods.append(built.method)
        notes.extend(f"part {label + 1}: {note}" for note in built.notes)
        alpha = max(alpha, built.alpha)
    # The strongest method names the whole: a wrap anywhere lies off the object there.
    method = min(methods, key=list(ProxyMethod).index)
    tally = ", ".join(f"{methods.count(m)} {m.value}" for m in ProxyMethod if m in methods)
    notes.insert(0, f"{len(areas)} parts far apart, each built at its own scale ({tally})")
    return _Built(mesh=trimesh.util.concatenate(pieces), method=method, alpha=alpha, notes=notes,
                  parts=len(areas))


def _build(mesh: trimesh.Trimesh, proxy: ProxyParams, problems: MeshProblems,
           budget: int, diag: float) -> _Built:
    """The proxy of one part within ``budget`` faces (before the last decimation to it):
    its lengths are fractions of its own diagonal ``diag`` (`_solid_diagonal`)."""
    alpha, offset, edge = proxy.alpha, proxy.offset, proxy.edge_length
    notes, alpha_m, out = [], 0.0, None
    force = proxy.mode == "always"
    if not force and (_only_holes(problems) or not _problem_phrases(problems)) and not _coarse(problems):
        # one manifold piece, far over the budget (a scan): the hole filling and the careful
        # decimation below run on a rough cut of it
        mesh = _thin_out(mesh, PRE_DECIMATE * budget)
    if not force and _only_holes(problems):
        out, method = _fill_small_holes(mesh, diag), ProxyMethod.FILL
    # A coarse mesh's flow needs edges no finer than its own features (`FEATURE_PERCENTILE`).
    flow_edge = max(edge * diag, float(np.percentile(mesh.edges_unique_length, FEATURE_PERCENTILE))
                    if _coarse(problems) else 0.0)
    if not force and _coarse(problems) and (out is not None or problems.watertight):
        # coarse closed pieces (filled, or boxes stacked into a table, crossing or not):
        # refine them; the walks run on each piece, buried faces drip nowhere (`find_drips`)
        edge_m = _edge_for_budget(float(mesh.area), flow_edge, budget)
        refined = _refine(mesh if out is None else out, edge_m, offset * diag)
        if refined is None:
            notes.append("refining broke the surface, it is wrapped instead")
        out, method = refined, ProxyMethod.REFINE
    if out is None and not force and not _problem_phrases(problems) and problems.faces > budget:
        out, method = mesh, ProxyMethod.DECIMATE  # clean, only too detailed
    if out is None:
        area = float(mesh.area)
        alpha_m = alpha * diag
        needed = float(np.sqrt(WRAP_FACE_FACTOR * area / min(budget, MAX_WRAP_FACES)))
        if needed > alpha_m:
            if needed > MAX_ALPHA * diag:
                raise InputError(
                    f"the mesh's surface ({area:.3g} m^2) is {area / diag ** 2:.1f} times its bounding-box "
                    f"diagonal squared: wrapping it in {min(budget, MAX_WRAP_FACES)} faces "
                    f"(proxy.face_budget={budget}) would need an alpha "
                    f"of {needed / diag:.3g} of the diagonal (at most {MAX_ALPHA}); raise proxy.face_budget "
                    "or simplify the mesh")
            notes.append(f"wrap alpha raised to {needed / diag:.3g} of the diagonal to fit the face budget")
            alpha_m = needed
        offset_m = min(offset * diag, alpha_m)
        wrapped = _wrap(mesh, alpha_m, offset_m)
        if len(wrapped.faces) == 0:
            raise InputError("the alpha wrap of this mesh came out empty; set proxy.mode: never "
                             "to let the water run on the mesh as it is")
        out = _remesh(wrapped, _edge_for_budget(wrapped.area, flow_edge, budget), offset_m)
        if not out.is_watertight:  # remeshing pinched a thin part: the wrap itself is sound
            notes.append("remeshing broke the surface, the raw wrap is used")
            out = wrapped
        method = ProxyMethod.WRAP
    return _Built(mesh=out, method=method, alpha=alpha_m, notes=notes)


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
