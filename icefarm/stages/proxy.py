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

Why a mesh needs a proxy (`proxy_reason`) and moving drip points found on the proxy back
onto the real mesh (`snap_to_surface`, so the icicles hang from the object itself) are
`icefarm.stages.proxy_checks`.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from dataclasses import dataclass

import numpy as np
import trimesh

from ..errors import InputError
from ..geometry import signed_volume
from ..mesh import MeshProblems, detect_problems
from ..meshlab import current, meshset
from ..params import ProxyParams
from .parts import group_pieces, piece_boxes
from .proxy_checks import boundary_loops, is_coarse, only_holes, problem_phrases, proxy_reason, solid_diagonal

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
    return None if problem_phrases(detect_problems(filled, self_intersections=True)) else filled


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
    diag = solid_diagonal(mesh)
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
        diag = solid_diagonal(part)
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
    its lengths are fractions of its own diagonal ``diag`` (`solid_diagonal`)."""
    alpha, offset, edge = proxy.alpha, proxy.offset, proxy.edge_length
    notes, alpha_m, out = [], 0.0, None
    force = proxy.mode == "always"
    if not force and (only_holes(problems) or not problem_phrases(problems)) and not is_coarse(problems):
        # one manifold piece, far over the budget (a scan): the hole filling and the careful
        # decimation below run on a rough cut of it
        mesh = _thin_out(mesh, PRE_DECIMATE * budget)
    if not force and only_holes(problems):
        out, method = _fill_small_holes(mesh, diag), ProxyMethod.FILL
    # A coarse mesh's flow needs edges no finer than its own features (`FEATURE_PERCENTILE`).
    flow_edge = max(edge * diag, float(np.percentile(mesh.edges_unique_length, FEATURE_PERCENTILE))
                    if is_coarse(problems) else 0.0)
    if not force and is_coarse(problems) and (out is not None or problems.watertight):
        # coarse closed pieces (filled, or boxes stacked into a table, crossing or not):
        # refine them; the walks run on each piece, buried faces drip nowhere (`find_drips`)
        edge_m = _edge_for_budget(float(mesh.area), flow_edge, budget)
        refined = _refine(mesh if out is None else out, edge_m, offset * diag)
        if refined is None:
            notes.append("refining broke the surface, it is wrapped instead")
        out, method = refined, ProxyMethod.REFINE
    if out is None and not force and not problem_phrases(problems) and problems.faces > budget:
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
