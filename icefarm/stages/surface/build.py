"""Stage 4: icicles, bases and glaze fused into one mesh."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import trimesh

from ...geometry import arc_lengths
from ...metaballs import Balls, concat_balls, face_estimate, fuse_fields, march_blocks, sample_field
from ...metaballs.clean import clean_slivers, sliver_candidates
from ...params import GlazeParams, SurfaceParams
from ...spatial import ray_caster
from ..drips import DripResult
from ..trajectories import TrajectoryResult
from ..water import WaterResult
from .bases import BASE_THICKNESS, base_balls, object_thickness
from .curtains import curtain_balls
from .detail import coarse_voxel, split_balls, surface_spacing
from .glaze import CoatSurface, glaze_field, glaze_thickness, wet_vertices
from .icicles import hang_roots, icicle_balls, root_shifts
from .measure import IcicleStats, measure_icicles
from .profile import grown_lengths, profile_args, smooth_radius
from .ripples import DEPTH_RANGE, carve_ripples_and_bands
from .runnels import carve_runnels
from .smooth import coat_vertices, smooth_glaze
from .tubes import tube_mesh

# Vertices closer than this many voxels are one, and faces flatter than it are flipped
# (`icefarm.metaballs.clean.clean_slivers`).
SLIVER = 1e-3
# Marching cubes gives about this many faces per voxel face of the icicles' estimated area
# (`budget_voxel`'s first guess, which `fitted_voxel` checks on the balls themselves).
FACES_PER_VOXEL_AREA = 1.3
# Share of ``surface.face_budget`` for the icicles and bases; the glaze coat gets the rest.
ICICLE_SHARE = 0.6
# `fitted_voxel`: counts at most this many voxels, and stops within this share of the last.
FIT_STEPS = 3
FIT_SLACK = 0.05


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
    icicles : IcicleStats or None
        The icicles' tip radius, taper, growth ratio, profile exponent and ripples, measured
        on the mesh (None when ``build_ice`` was asked not to measure).
    balls : int
        Metaballs of the icicles, bases, curtains and ``extra_balls`` (0 in tubes mode;
        the coat has none).
    curtain_area : float
        Area of the curtains between close trunks (`curtain_balls`), square meters.
    axes : TrajectoryResult or None
        The branches the icicles were built on: stage 3's, with roots on a rim moved in
        under the object (`hang_roots`); what measures of the ice take as axes.
    coarse_voxel : float or None
        Voxel of the lattice the face budget meshed the icicles' thick parts on, meters
        (`coarse_voxel`): no ripple is carved where an icicle is that thick. None: one lattice.
    bands : (n,) float32 or None
        How far under a ripple crest each vertex lies, 0 to 1 (`ripple_bands`, read off the
        carve itself): where impure ice is milky. None: no ripples (pure water, tubes mode).
    """

    vertices: np.ndarray
    faces: np.ndarray
    icicles: IcicleStats | None
    balls: int
    curtain_area: float = 0.0
    axes: TrajectoryResult | None = None
    coarse_voxel: float | None = None
    bands: np.ndarray | None = None


@dataclass(frozen=True)
class IceInputs:
    """What stage 4 builds on: the object, the surface the water ran on and stages 1-3.

    Attributes
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
    exclude : (n,) bool, optional
        Flow-mesh vertices where no glaze may be (the sole the object stands on).
    coat_surface : CoatSurface, optional
        The surface the glaze grows on, with its water and excluded vertices, when not
        ``flow_mesh`` (the object under a wrap, `glaze.carry_water`); ``water`` and
        ``exclude`` still say where the icicles' water came from.
    extra_balls : Balls, optional
        More metaballs for the icicles' field, in meters. None (or no curtain) leaves the
        mesh exactly as without them.
    cast : callable, optional
        A ray caster of ``flow_mesh`` to reuse (`icefarm.spatial.ray_caster`).
    """

    object_mesh: trimesh.Trimesh
    flow_mesh: trimesh.Trimesh
    water: WaterResult
    drips: DripResult
    trajectories: TrajectoryResult
    exclude: np.ndarray | None = None
    coat_surface: CoatSurface | None = None
    extra_balls: Balls | None = None
    cast: Callable | None = None


def build_ice(inputs: IceInputs, surface: SurfaceParams, glaze: GlazeParams, gravity: np.ndarray,
              rng: np.random.Generator, *, measure: bool = True,
              note: Callable[[str], None] | None = None) -> IceResult:
    """Stage 4: icicles, their bases and glaze ice as one mesh (paper 4.4).

    ``surface.mode == "metaballs"``: one watertight mesh of the icicle chains and the
    bases (one field at ``surface.voxel_size``) and the glaze (`glaze_field`, on its own
    coarser lattice), joined by a boolean union where they meet (`fuse_fields`); the
    ripples are then carved in and slivers cleaned. ``surface.curtain`` above 0 joins
    close trunks with sheets (`curtain_balls`); ``extra_balls`` (the mounds and stalagmites
    of `icefarm.stages.surface.ground_ice`) join the same field. ``"tubes"``: each branch as
    its own closed tube (`tube_mesh`), without bases, glaze, curtains or extra balls: an
    instant preview.

    Parameters
    ----------
    inputs : IceInputs
        The object, the flow surface, stages 1-3's results and what else joins the ice.
    surface, glaze : SurfaceParams, GlazeParams
        The two groups of the resolved parameters (``params.surface``, ``params.glaze``).
    gravity : (3,) float
        Direction of gravity (orients the first frame of each tube).
    rng : numpy.random.Generator
        Noise and base balls of the icicles; the glaze draws from a stream spawned off it
        (`numpy.random.Generator.spawn`), so its balls, drops and runnels stay the same
        whatever the icicles draw (a sweep over them keeps one glaze).
    measure : bool
        Measure the icicles on the mesh (`measure_icicles`); False leaves
        ``IceResult.icicles`` None (a caller that times the modelling alone measures apart).
    note : callable, optional
        ``note(text)`` as each part starts (glaze coat, icicle field, meshing, ripples,
        clean-up): progress for a caller that shows it.

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
    g = _checked(inputs, gravity)
    if surface.mode == "tubes":
        verts, faces = tube_mesh(inputs.trajectories, surface, g)
        ice = IceResult(verts, faces, None, 0, 0.0, inputs.trajectories, None, None)
    else:
        ice = _metaball_ice(inputs, surface, glaze, g, rng, note or (lambda text: None))
    if measure:
        ice = dataclasses.replace(ice, icicles=measure_icicles(ice.vertices, ice.faces, ice.axes, surface))
    return ice


def _checked(inputs: IceInputs, gravity) -> np.ndarray:
    """Gravity as ``(3,) float64``, once the inputs' shapes agree (else ValueError)."""
    water, drips, trajectories = inputs.water, inputs.drips, inputs.trajectories
    g = np.asarray(gravity, dtype=np.float64).reshape(-1)
    if g.shape != (3,) or not np.isfinite(g).all() or not g.any():
        raise ValueError(f"gravity must be 3 finite numbers, not all zero; got {gravity!r}")
    nv = len(inputs.flow_mesh.vertices)
    for name in ("supply", "water", "d_up", "d_down"):
        if len(getattr(water, name)) != nv:
            raise ValueError(f"water.{name} has {len(getattr(water, name))} values for {nv} flow-mesh vertices")
    k = len(drips.positions)
    if not (len(drips.normals) == len(drips.water) == len(drips.faces) == k):
        raise ValueError("drips.positions, normals, water and faces differ in length")
    if len(drips.faces) and (np.min(drips.faces) < 0 or np.max(drips.faces) >= len(inputs.object_mesh.faces)):
        raise ValueError("drips.faces index faces outside object_mesh")
    off = np.asarray(trajectories.branch_offsets)
    if off.ndim != 1 or len(off) != trajectories.n_branches + 1 or (len(off) and off[-1] != len(trajectories.points)):
        raise ValueError("trajectories.branch_offsets must have n_branches + 1 entries ending at len(points)")
    return g


@dataclass(frozen=True)
class _Lattices:
    """The icicles' balls on their lattices and the glaze coat's field: ``voxel`` (m) of the fine
    lattice, ``coarse`` (m, None: one lattice) with ``ice`` on it and the thin rest ``fine``
    on the fine one, ``field``/``marched`` already sampled and marched (or None)."""

    voxel: float
    coarse: float | None
    ice: Balls
    fine: Balls | None
    field: object
    marched: object
    coat: object


def _metaball_ice(inputs: IceInputs, surface: SurfaceParams, glaze: GlazeParams, g: np.ndarray,
                  rng: np.random.Generator, note: Callable[[str], None]) -> IceResult:
    """``surface.mode == "metaballs"``: the balls, their lattices and the coat, meshed and
    united, rippled and cleaned (not measured)."""
    object_mesh, flow_mesh, drips = inputs.object_mesh, inputs.flow_mesh, inputs.drips
    trajectories, cast, k = inputs.trajectories, inputs.cast, len(inputs.drips.positions)
    own_cast = cast if flow_mesh is object_mesh and cast is not None else ray_caster(object_mesh)
    if k:  # roots on a rim move in under the object: stage 4 builds and measures on these axes
        thickness = object_thickness(object_mesh, drips.positions, drips.normals, own_cast)
        trajectories = hang_roots(trajectories, surface, root_shifts(drips.normals, g, BASE_THICKNESS * thickness))
    glaze_rng = rng.spawn(1)[0]
    chains = icicle_balls(trajectories, surface, rng)
    ice = concat_balls(chains,
                       base_balls(object_mesh, drips, surface, rng, _root_radius(trajectories, k, surface),
                                  cast=own_cast, gravity=g))
    curtains = curtain_balls(trajectories, surface, g)
    more = [b for b in (curtains.balls, inputs.extra_balls) if b is not None and len(b)]
    if more:  # nothing appended otherwise: the field's sums stay bit for bit
        ice = concat_balls(ice, *more)
    coat_surface = inputs.coat_surface
    if coat_surface is None:
        coat_surface = CoatSurface(flow_mesh, inputs.water, inputs.exclude)
    coat_cast = cast if coat_surface.mesh is flow_mesh else own_cast if coat_surface.mesh is object_mesh else None
    budget = surface.face_budget if inputs.water.storm is not None else 0
    chain = np.arange(len(ice)) < len(chains)
    lat = _lattices(ice, chain, trajectories, object_mesh, coat_surface, coat_cast, surface, glaze, budget,
                    glaze_rng, note)
    verts, faces, bands = _meshed(lat, trajectories, coat_surface, surface, glaze, g, glaze_rng, note)
    return IceResult(verts, faces, None, len(lat.ice), curtains.area, trajectories, lat.coarse, bands)


def _lattices(ice: Balls, chain: np.ndarray, trajectories: TrajectoryResult, object_mesh: trimesh.Trimesh,
              coat_surface: CoatSurface, coat_cast, surface: SurfaceParams, glaze: GlazeParams, budget: int,
              glaze_rng: np.random.Generator, note: Callable[[str], None]) -> _Lattices:
    """The lattices that hold the face ``budget`` (0: ``surface.voxel_size``), the glaze coat
    sampled while the one lattice, where it is enough, is marched beside it."""
    voxel = surface.voxel_size
    extent = float(np.linalg.norm(np.ptp(object_mesh.vertices, axis=0)))
    # One lattice, rippled, whenever it holds the budget (fitted without the coat); the
    # coarse lattice (whose thick parts carry no ripple) only where even the tips'
    # coarsest voxel would not.
    coarse, fine, one = None, None, True
    if budget:
        share = ICICLE_SHARE * budget
        guess = budget_voxel(trajectories, surface, share)
        one_lattice = functools.lru_cache(maxsize=None)(lambda v: _icicle_faces(v, None, ice, None))
        voxel = fitted_voxel(one_lattice, surface, guess, share)
        one = one_lattice(voxel) <= (1 + FIT_SLACK) * share  # counted already when the fit settled
    with ThreadPoolExecutor(1) as pool:
        # A lattice that needs no coat is sampled and marched while the coat's band runs
        # (its kernel leaves the GIL that marching cubes holds): Table 2's dragon's stage 4
        # runs about a tenth faster (medians of three alternated rounds of five);
        # the 3 m house's preview peaks at 1.67 GB either way.
        early = pool.submit(_marched, ice, voxel) if one and len(ice) else None
        note(f"glaze coat over {len(coat_surface.mesh.faces):,} faces")
        coat = glaze_field(coat_surface.mesh, coat_surface.water, glaze, glaze_rng, exclude=coat_surface.exclude,
                           cast=coat_cast, face_budget=(1.0 - ICICLE_SHARE) * budget)

        def lattices(fine_voxel: float):
            # (coarse voxel, the balls on it, the thin rest on the fine one)
            coarse = coarse_voxel(fine_voxel, extent, surface.error_px, *_ripple(surface))
            if coarse is None:
                return None, ice, None
            clearance = _coat_reach(coat_surface.mesh, coat_surface.water, glaze, coat, coarse, fine_voxel)
            return coarse, *split_balls(ice, coarse, coat_surface.mesh.vertices, clearance, chain)

        if not one:
            voxel = fitted_voxel(lambda v: _icicle_faces(v, *lattices(v)), surface, guess, share)
            coarse, ice, fine = lattices(voxel)
        field, marched = early.result() if early is not None else (None, None)
    return _Lattices(voxel, coarse, ice, fine, field, marched, coat)


def _meshed(lat: _Lattices, trajectories: TrajectoryResult, coat_surface: CoatSurface, surface: SurfaceParams,
            glaze: GlazeParams, g: np.ndarray, glaze_rng: np.random.Generator, note: Callable[[str], None]):
    """The icicles' fields and the coat meshed and united, rippled, cleaned of slivers and the
    coat smoothed and carved: ``(vertices (n, 3), faces (m, 3), bands (n,) or None)``."""
    voxel, coarse, ice, fine, coat = lat.voxel, lat.coarse, lat.ice, lat.fine, lat.coat
    voxel_ice = voxel if coarse is None else coarse
    note(f"icicle field: {len(ice) + (len(fine) if fine is not None else 0):,} balls at "
         f"{voxel_ice * 1000:.2g}" + (f" and {voxel * 1000:.2g}" if fine is not None else "") + " mm")
    field = lat.field
    if field is None and len(ice):
        field = sample_field(ice, voxel_ice)
    fields = (field, coat, sample_field(fine, voxel) if fine is not None and len(fine) else None)
    blocks = sum(len(f.blocks) for f in fields if f is not None)
    note(f"meshing {blocks:,} blocks and uniting the glaze")
    verts, faces = fuse_fields(*fields, a_marched=lat.marched)
    thin = sliver_candidates(verts, [f for f in fields if f is not None], SLIVER * voxel)
    note(f"ripples on {len(faces):,} faces")
    verts, bands = carve_ripples_and_bands(verts, trajectories, profile_args(surface), max_radius=coarse)
    note("clean-up")
    verts, faces, kept = clean_slivers(verts, faces, SLIVER * voxel, near=thin)
    if bands is not None:
        bands = bands[kept]
    if coat is not None and glaze.mode == "coat" and (glaze.smoothing or glaze.runnels > 0):
        on_coat = coat_vertices(verts, faces, coat.voxel, [f for f in fields if f is not None and f is not coat],
                                coat_surface.mesh)
        verts = smooth_glaze(verts, faces, coat.voxel, on_coat, glaze.smoothing)
        verts = carve_runnels(verts, on_coat, coat_surface.mesh, g, glaze.runnels, coat.voxel, glaze_rng)
    return verts, faces, bands


def _ripple(surface: SurfaceParams) -> tuple[float, float]:
    """The deepest ripples' amplitude (some icicles' ripples are deeper than the parameter's,
    `ripples.DEPTH_RANGE`) and their wavelength, meters."""
    prof = profile_args(surface)
    return prof.amplitude * DEPTH_RANGE[1], (2 * np.pi / prof.frequency if prof.frequency > 0 else 0.0)


def _coat_reach(flow_mesh: trimesh.Trimesh, water: WaterResult, glaze: GlazeParams, coat, coarse: float,
                fine: float) -> float:
    """How far from the flow mesh's vertices the glaze coat and the margins of its union
    with the icicles' coarse part may reach, meters (`detail.split_balls`'s clearance)."""
    reach = surface_spacing(flow_mesh.vertices, flow_mesh.faces) + glaze.edge
    if coat is not None:
        wet = wet_vertices(water)
        thick = glaze_thickness(water, glaze)
        reach += (float(thick[wet].max()) if wet.any() else 0.0) + 2.0 * coat.voxel
    return reach + 2.0 * (math.sqrt(3) + 2.0) * (coarse + fine)


def budget_voxel(traj: TrajectoryResult, surface: SurfaceParams, faces: float) -> float:
    """The icicles' voxel edge, meters: ``surface.voxel_size``, or coarser so that their mesh
    holds about ``faces`` faces (`FACES_PER_VOXEL_AREA` per voxel face of their area, each
    branch a solid of its profile: mean radius ``tip + 4/7 t L``), never past the tip radius
    (a tip narrower than two voxels would break up)."""
    _, lengths = arc_lengths(traj.points, traj.branch_offsets)
    growth = traj.growth(surface.growth_ratio)
    area = float((2.0 * np.pi * (surface.tip_radius + 4.0 / 7.0 * growth * lengths) * lengths).sum())
    if faces <= 0 or area <= 0:
        return surface.voxel_size
    wanted = np.sqrt(FACES_PER_VOXEL_AREA * area / faces)
    return float(min(max(surface.voxel_size, wanted), max(surface.voxel_size, surface.tip_radius)))


def fitted_voxel(count: Callable[[float], int], surface: SurfaceParams, guess: float, faces: float) -> float:
    """The icicles' voxel edge, meters, at which their mesh holds about ``faces`` faces:
    from ``guess`` (`budget_voxel`'s estimate from the branches' profiles), scaled by the
    square root of the miss that ``count`` (a voxel to the faces marching would make,
    `_icicle_faces`) reports, at most `FIT_STEPS` times; between ``surface.voxel_size`` and
    the tip radius, as in `budget_voxel`.

    The profiles leave out bases, curtains and where icicles merge: on the real-size bench
    they say 1.8 M faces at 1.14 mm where marching makes 3.9 M; counting on the balls
    themselves predicts it within 3 %.
    """
    lo, hi = surface.voxel_size, max(surface.voxel_size, surface.tip_radius)
    voxel = float(np.clip(guess, lo, hi))
    for _ in range(FIT_STEPS):
        counted = count(voxel) if faces > 0 else 0
        if counted == 0:
            break
        wanted = float(np.clip(voxel * math.sqrt(counted / faces), lo, hi))
        if abs(wanted - voxel) <= FIT_SLACK * voxel:
            break
        voxel = wanted
    return voxel


def _marched(balls: Balls, voxel: float):
    """The field of ``balls`` on a lattice of ``voxel`` (m) and its marching (`fuse_fields`'
    ``a_marched``); (None, None) for no field."""
    field = sample_field(balls, voxel)
    return (None, None) if field is None else (field, march_blocks(field.values, field.blocks, field.level))


def _icicle_faces(fine: float, coarse: float | None, balls: Balls, thin: Balls | None) -> int:
    """About the faces marching makes of ``balls`` on the ``coarse`` lattice (on the
    ``fine`` one if None) and of ``thin`` on the fine one, without marching them: the
    fine lattice counted at twice its voxel (`face_estimate`; faces go as 1 / voxel^2)."""
    parts = [(balls, fine, 4)] if coarse is None else [(balls, coarse, 1), (thin, fine, 4)]
    total = 0
    for b, voxel, scale in parts:
        field = sample_field(b, voxel * math.sqrt(scale)) if b is not None and len(b) else None
        total += scale * face_estimate(field) if field is not None else 0
    return total


def _root_radius(traj: TrajectoryResult, k: int, surface: SurfaceParams) -> np.ndarray:
    """(k,) radius of each icicle's trunk where it leaves the object (the tip radius for a
    drip point without a trunk), meters."""
    _, lengths = arc_lengths(traj.points, traj.branch_offsets)
    trunk_length = np.zeros(k)
    trunks = np.flatnonzero(np.asarray(traj.branch_parent) < 0)
    trunk_length[np.asarray(traj.branch_icicle)[trunks]] = grown_lengths(lengths[trunks], traj.cut[trunks])
    prof = profile_args(surface)
    growth = np.full(k, prof.growth)
    growth[np.asarray(traj.branch_icicle)[trunks]] = traj.growth(surface.growth_ratio)[trunks]
    return smooth_radius(0.0, trunk_length, dataclasses.replace(prof, growth=growth))
