"""Glaze ice over the wet surface (paper 4.4.4, Equation 3): a clear coat, the paper's
metaballs, or none; the surface the coat hugs, with the water carried onto it (`carry_water`).
Its measurement on the finished ice is `icefarm.stages.surface.glaze_measure`.

Every wet vertex of the flow mesh gets the thickness of Equation 3,
``rgi = minGI + s [dUp lt + dDown (1 - lt)]``: lt = 0 puts the ice high up (water freezes
where it lands), lt = 1 low down (it runs down before freezing), 0.5 evens it out.

``glaze.mode``:

* ``coat`` (default): one continuous clear coat exactly that thick over the wet faces,
  thinning to nothing over ``glaze.edge`` past them (`icefarm.stages.surface.coat`). Its
  thickness does not depend on a ball count, the size of the object or its mesh.
* ``metaballs``: the paper's construction, ``glaze.density`` balls per square meter of wet
  surface, each making the sheet ``rgi`` thick around it (`glaze_balls`); at the densities
  a machine can afford it reads as lumps and holes.
* ``none``: no glaze.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ...geometry import random_barycentric
from ...metaballs import Field, sample_field
from ...metaballs.balls import NO_BALLS, Balls, sheet_balls
from ...params import GlazeParams
from ...spatial import nearest, point_index, ray_caster
from ...tol import tol
from ..water import WaterResult
from .coat import CoatOptions, coat_field

# With the glaze on its own coarser lattice, its sheet is at least this many glaze voxels
# thick (the extra thickness goes inside the object), so marching cubes tears it less.
COAT_SHEET = 2.0
# Under a physical storm the coat's lattice is at least its median thickness over this
# many voxels: a 25 mm coat at 4 mm voxels is millions of faces no lookdev view resolves.
STORM_COAT_VOXELS = 4.0
# The coat's mesh holds about this many faces per voxel face of the wet area (both its
# sides, its rims and the creases it follows; 7.6 measured on the 3 m house).
COAT_FACES_PER_VOXEL_AREA = 8.0
# `carry_water` splits the object's edges down to this many times the flow mesh's median
# edge: as fine as the wrap's (1), the teapot's spout takes the wrap's patchy wet and dry
# faces as islands of coat with ragged rims; at 3 its coat is as smooth as unsplit.
CARRY_EDGE = 3.0


def wet_vertices(water: WaterResult, exclude: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: vertices of the water supply or with water (under a physical storm: with
    ice), less the ``exclude`` ones."""
    if water.storm is not None:  # a physical storm: wet where ice froze
        wet = np.asarray(water.storm.ice) > 0
    else:
        wet = np.asarray(water.supply, dtype=bool) | (np.asarray(water.water) > 0)
    if exclude is not None:
        wet = wet & ~np.asarray(exclude, dtype=bool).reshape(-1)
    return wet


def glaze_thickness(water: WaterResult, glaze: GlazeParams) -> np.ndarray:
    """(n,) float: Equation 3's ``rgi = minGI + s [dUp lt + dDown (1 - lt)]`` per vertex, in meters;
    under a physical storm, the ice it froze there (`icefarm.stages.storm`), plus minGI."""
    if water.storm is not None:
        return glaze.min_radius + np.asarray(water.storm.ice, dtype=np.float64)
    lt = glaze.lifetime
    d_up = np.asarray(water.d_up, dtype=np.float64)
    d_down = np.asarray(water.d_down, dtype=np.float64)
    return glaze.min_radius + glaze.scale * (d_up * lt + d_down * (1 - lt))


@dataclass(frozen=True)
class CoatSurface:
    """A surface for the glaze coat to hug, with the water of stages 1-2 on it.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        In meters, outward normals.
    water : WaterResult
        Per vertex of ``mesh`` (``top``, ``bottom`` and ``hits`` still those of the surface
        the water ran on).
    exclude : (n,) bool or None
        Vertices of ``mesh`` that get no glaze (the sole an object stands on; over a wrap,
        also those only on faces buried in the object, `_open`).
    """

    mesh: trimesh.Trimesh
    water: WaterResult
    exclude: np.ndarray | None = None


def carry_water(object_mesh: trimesh.Trimesh, flow_mesh: trimesh.Trimesh, water: WaterResult,
                exclude: np.ndarray | None, reach: float) -> CoatSurface:
    """The object's own surface for the glaze coat, with the water that stages 1-2 left on a
    wrap around it (`icefarm.stages.proxy`) carried over.

    A wrap lies up to its alpha off the object, on either side of it. A coat hugging the wrap
    then crosses the object: the teapot's spout (under its wrap by a median 1.4 mm) comes
    out through the coat in patches whose outlines render as dark cracks, whatever the
    coat's sampling or thickness. On the object itself the coat has no such outlines.

    The object's long edges are split (midpoint subdivision, `icefarm.stages.storm.refine`;
    not on an object with non-manifold edges, which it refuses) down to `CARRY_EDGE` times
    the flow mesh's, so that its wet and dry parts follow the water; each of its vertices
    takes the water of the flow-mesh vertex nearest to it, and none where that lies farther
    than ``reach`` (object surface the wrap left out: the inside of a spout or a gap it
    bridged) or where it lies on faces buried in the object (`_open`). Each connected piece is
    turned to face the way the wrap does (`_outward`).

    Parameters
    ----------
    object_mesh, flow_mesh : trimesh.Trimesh
        In meters; the flow mesh is closed and wound outward.
    water : WaterResult
        Per vertex of ``flow_mesh``.
    exclude : (n,) bool or None
        Flow-mesh vertices that get no glaze.
    reach : float
        Meters; at least the wrap's alpha.

    Returns
    -------
    CoatSurface
    """
    from ..storm import refine

    try:
        mesh = refine(object_mesh, CARRY_EDGE * float(np.median(flow_mesh.edges_unique_length)))
    except ValueError:  # subdivision needs a 2-manifold: the object as it is
        mesh = object_mesh
    vertices = np.asarray(mesh.vertices)
    index = point_index(flow_mesh.vertices)
    distance, source = nearest(index, vertices)
    mesh = _outward(mesh, flow_mesh, index, reach)
    near = distance <= reach
    shown = _open(mesh, wet_vertices(water)[source] & near)

    def carried(values, dry):
        return np.where(near, np.asarray(values)[source], dry)

    storm = water.storm
    if storm is not None:
        storm = dataclasses.replace(storm, sky=carried(storm.sky, False), catch=carried(storm.catch, 0.0),
                                    ice=carried(storm.ice, 0.0), shed=carried(storm.shed, 0.0))
    moved = dataclasses.replace(water, supply=carried(water.supply, False), water=carried(water.water, 0.0),
                                top=np.asarray(water.top)[source], d_up=carried(water.d_up, 0.0),
                                bottom=np.asarray(water.bottom)[source], d_down=carried(water.d_down, 0.0),
                                storm=storm)
    sole = np.zeros(len(vertices), dtype=bool) if exclude is None else np.asarray(exclude, dtype=bool)[source] & near
    return CoatSurface(mesh, moved, sole | ~shown)


def _open(mesh: trimesh.Trimesh, wet: np.ndarray) -> np.ndarray:
    """``(n,) bool``: the vertices of ``mesh`` (wound outward) that are not wet (``wet``) only
    on faces buried in the object: a wet face whose normal, cast from just off its centre,
    first meets the object from behind (the inside of a part it lies in) is buried. One ray
    a face, and no closed surface needed (parity counts go wrong on the chair's open,
    non-manifold seat and dry a third of its wet faces).

    A wrap's water reaches the object's surface inside the wrap whether or not it is buried:
    on the box soup 13 % of the wet area (25 % with a coarser wrap), on the teapot 4.8 % (the
    spout's root inside the body, the lid's rim). A coat grown there lies inside the opaque
    object, or comes out through its surface where that is closer than the coat is thick, and
    the glaze measured on it reads 38.7 mm at p90 on the box soup.
    """
    faces = np.asarray(mesh.faces)
    wet_face = np.flatnonzero(wet[faces].sum(axis=1) >= 2)
    shown = np.ones(len(mesh.vertices), dtype=bool)
    if len(wet_face) == 0:
        return shown
    normal = mesh.face_normals[wet_face]
    _, hit = ray_caster(mesh)(mesh.triangles_center[wet_face] + tol.ray_lift_m * normal, normal)
    buried = hit >= 0
    buried[buried] = np.einsum("kd,kd->k", mesh.face_normals[hit[buried]], normal[buried]) > 0
    seen = np.zeros(len(mesh.vertices), dtype=bool)
    seen[faces[wet_face[~buried]]] = True
    shown[faces[wet_face[buried]].ravel()] = False
    return shown | seen


def _outward(mesh: trimesh.Trimesh, wrap: trimesh.Trimesh, index, reach: float) -> trimesh.Trimesh:
    """``mesh`` with each connected piece turned, whole, to face the way the wrap around it
    does: by the area of its faces within ``reach`` of the wrap (``index``, `point_index` of
    its vertices), weighted by the cosine between each face's normal and the nearest wrap
    vertex's. `icefarm.mesh.prepare` cannot turn the pieces of a mesh with non-manifold edges:
    the chair's seat (its bowl, 1,746 faces) faces 99 % of its area against its wrap, and its
    coat would grow inside the shell, leaving the bowl bare. Single faces are not turned: near
    creases and a spout's mouth the nearest wrap vertex faces elsewhere (216 of the teapot's
    6,320 faces would turn wrongly and break its coat into flakes)."""
    faces = np.asarray(mesh.faces)
    distance, nearest_vertex = nearest(index, mesh.triangles_center)
    cosine = np.einsum("kd,kd->k", mesh.face_normals, wrap.vertex_normals[nearest_vertex])
    piece = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    vote = np.bincount(piece, weights=mesh.area_faces * cosine * (distance <= reach))
    turn = vote[piece] < 0
    if not turn.any():
        return mesh
    return trimesh.Trimesh(mesh.vertices, np.where(turn[:, None], faces[:, ::-1], faces), process=False)


def glaze_field(flow_mesh: trimesh.Trimesh, water: WaterResult, glaze: GlazeParams, rng: np.random.Generator,
                exclude: np.ndarray | None = None, cast=None, face_budget: float = 0.0) -> Field | None:
    """The glaze as a field on the ``glaze.voxel_size`` lattice, per ``glaze.mode``.

    Fuse it with the icicles' field by ``icefarm.metaballs.fuse_fields(icicles, glaze)``:
    one watertight mesh.

    Parameters
    ----------
    flow_mesh : trimesh.Trimesh
        The surface stages 1-2 ran on, in meters, outward normals.
    water : WaterResult
        Per vertex of ``flow_mesh``.
    glaze : GlazeParams
        The resolved ``glaze`` group.
    rng : numpy.random.Generator
        Ball positions (``metaballs`` mode only; the coat is deterministic).
    exclude : (n,) bool, optional
        Flow-mesh vertices where no glaze may be (the sole an object stands on): no ice
        touches them.
    cast : callable, optional
        An `icefarm.spatial.ray_caster` of ``flow_mesh``, if one is at hand (the coat
        casts a ray under each of its surface samples to find thin walls).
    face_budget : float
        Under a physical storm, the coat's lattice coarsens so that its mesh holds about
        this many faces (`COAT_FACES_PER_VOXEL_AREA`); 0: off.

    Returns
    -------
    Field or None
        None for ``mode: none`` or a dry surface.
        Coat mode: level 1, stored so that marching interpolates the signed distance.

    Raises
    ------
    InputError
        ``glaze.voxel_size`` too fine for the extent of the glaze.
    """
    if glaze.mode == "none":
        return None
    if glaze.mode == "metaballs":
        balls = glaze_balls(flow_mesh, water, glaze, rng, min_sheet=COAT_SHEET * glaze.voxel_size,
                            exclude=exclude)
        return sample_field(balls, glaze.voxel_size, name="glaze.voxel_size") if len(balls) else None
    thickness, wet = glaze_thickness(water, glaze), wet_vertices(water)
    voxel = glaze.voxel_size
    if water.storm is not None and wet.any():  # a storm's centimetre coat needs no millimetre voxels
        voxel = max(voxel, float(np.median(thickness[wet])) / STORM_COAT_VOXELS)
        if face_budget > 0:
            wet_area = float(flow_mesh.area_faces[wet[flow_mesh.faces].sum(axis=1) >= 2].sum())
            voxel = max(voxel, math.sqrt(COAT_FACES_PER_VOXEL_AREA * wet_area / face_budget))
    return coat_field(flow_mesh, thickness, wet, CoatOptions(voxel, glaze.edge, "glaze.voxel_size"), exclude=exclude,
                      cast=cast)


def glaze_balls(flow_mesh: trimesh.Trimesh, water: WaterResult, glaze: GlazeParams,
                rng: np.random.Generator, min_sheet: float = 0.0,
                exclude: np.ndarray | None = None) -> Balls:
    """``glaze.density`` balls per square meter spread at random over the wet surface
    (paper 4.4.4, Equation 3: the ``metaballs`` mode).

    Wet vertices are those of the water supply or with water > 0 (less ``exclude``); wet
    faces have at least two and no excluded one. Points are drawn area-weighted and
    stratified over the wet faces (`spread_on_faces`), so the glaze sheet has fewer lumps
    and holes than independent draws give. Each ball makes the ice ``rgi`` thick
    (`glaze_thickness`, dUp and dDown interpolated).

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
    glaze : GlazeParams
        The resolved ``glaze`` group (``density``, ``min_radius``, ``scale``, ``lifetime``;
        ``mode: none`` gives no balls).
    rng : numpy.random.Generator
    min_sheet : float
        Least total thickness of the sheet, in meters (0: the sheet is ``2 rgi`` thick).
    exclude : (n,) bool, optional
        Flow-mesh vertices that get no glaze.

    Returns
    -------
    Balls
    """
    if glaze.mode == "none":
        return NO_BALLS
    wet = wet_vertices(water, exclude)
    faces = flow_mesh.faces
    ok = wet[faces].sum(axis=1) >= 2
    if exclude is not None:
        ok &= ~np.asarray(exclude, dtype=bool)[faces].any(axis=1)
    wet_faces = np.flatnonzero(ok)
    areas = flow_mesh.area_faces[wet_faces]
    ngi = int(round(glaze.density * areas.sum()))
    if ngi == 0 or len(wet_faces) == 0 or areas.sum() <= 0:
        return NO_BALLS
    tris = flow_mesh.triangles[wet_faces]
    pick = spread_on_faces(tris.mean(axis=1), areas, ngi, rng)
    fv = faces[wet_faces[pick]]
    bary = random_barycentric(len(pick), rng)
    pts = (flow_mesh.vertices[fv] * bary[:, :, None]).sum(axis=1)
    radius = (glaze_thickness(water, glaze)[fv] * bary).sum(axis=1)
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
