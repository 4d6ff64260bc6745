"""Ripples carved into the icicles of the ice mesh (paper 4.4.1, Equation 1's ``as sin(x fs)``).

A chain of Gaussian balls of width s keeps ``exp(-(fs s / 2)^2)`` of a ripple along it: at
1 cm ripples, 3 % on a 1 cm thick base, 70 % at the tip (measured: 0.07 mm realised of
0.6 mm asked on a 12 cm icicle). So the chains carry the smooth profile and the ripple is a
displacement of the mesh's vertices around each branch, which keeps the mesh watertight
and the ripple exactly as deep as asked, at any frequency the voxel resolves.

The ripple is natural rather than a stack of identical rings (they read as a coiled
spring at lookdev): its wavelength wanders, its crests tilt, fork and fade around the
trunk, it runs deep in patches with calm stretches between, and it is quiet near the tip
(`WANDER`, `TILT`, `FORK_SPACING`, `FADE_FLOOR`, `PATCH_FLOOR`, `TIP_QUIET`, `TIP_RISE`).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from ...geometry import arc_lengths, ragged_arange, within_box
from ...spatial import nearest, point_index
from ..trajectories import TrajectoryResult
from .profile import TIP_CALM, Profile, grown_lengths, points_along, smooth_radius

# Vertices farther from a branch's axis than this times its radius there (plus the ripple)
# belong to something else: a neighbour, the base ice, the glaze.
REACH = 1.3
# Ripples come in as the icicle widens: full once its radius exceeds the tip's by this
# many tip radii. A thin young icicle is smooth; a 0.7 mm ripple on a 3 mm straw reads as a
# string of beads (seen at lookdev), while on real icicles ripples run on the wide part.
RIPPLE_WIDENING = 1.0
GOLDEN_ANGLE = np.pi * (3 - np.sqrt(5))
RIPPLE_SEED = 0x1C1C1E  # each branch's ripple texture: its own stream, not the stage's
# Axis samples per ripple wavelength (and at least one per tip radius): each vertex takes
# its own arc length (its nearest sample's plus its offset along the axis), so the ripple's
# phase needs no finer samples; the amplitude's envelope is smooth at this spacing.
SAMPLES_PER_WAVE = 4
# The milky bands (`ripple_bands`) reach down the crests' flanks: at a trough they keep this
# share of a crest's milkiness, so the steep flanks, which refract what lies above into dark
# stripes, are frosted too.
BAND_FLOOR = 0.5


def carve_ripples(vertices: np.ndarray, traj: TrajectoryResult, prof: Profile,
                  max_radius: float | None = None) -> np.ndarray:
    """Move the ice mesh's vertices around each branch radially by the profile's ripple.

    Each vertex follows the nearest sample of the branch axes: at arc length x of a branch,
    it moves by ``as sin(x fs)`` (faded at the tip as in `profile_radius`, in over the
    first `ROOT_FADE` of the branch or its base radius if longer, where it meets the object,
    and in as the radius widens past the tip's, `RIPPLE_WIDENING`) away from the axis, with
    the texture of natural ripples (`WANDER` and the constants after it).

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices, in meters.
    traj : TrajectoryResult
    prof : Profile
        `profile_args` of the surface group (``amplitude`` is ``as * impurity``).
    max_radius : float, optional
        Ripples fade out from 0.8 of this radius to it (meters): where the icicles are
        thicker, their mesh is too coarse to carry them (`icefarm.stages.surface.detail`)
        and the error budget is coarser than they are deep.

    Returns
    -------
    (n, 3) float
        The moved vertices (a copy); the same array when there is no ripple.
    """
    return carve_ripples_and_bands(vertices, traj, prof, max_radius)[0]


def carve_ripples_and_bands(vertices: np.ndarray, traj: TrajectoryResult, prof: Profile,
                            max_radius: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """`carve_ripples` and the `ripple_bands` of the carved vertices, from one pass.

    The carve moves vertices across the axis only, so each keeps its place along the
    ripple: the bands read off the carve's own waves are those `ripple_bands` reads off the
    carved mesh (save a vertex whose nearest axis sample changes as it moves, at a bend),
    without a second search of the mesh.

    Returns
    -------
    vertices : (n, 3) float
        As `carve_ripples`.
    bands : (n,) float32 or None
        As `ripple_bands`.
    """
    waves = _waves(vertices, traj, prof, max_radius)
    if waves is None:
        return vertices, None
    out = np.array(vertices, dtype=np.float64, copy=True)
    out[waves.near] += (waves.wave / waves.dist)[:, None] * waves.radial
    return out, _bands(len(vertices), waves, prof.amplitude)


def ripple_bands(vertices: np.ndarray, traj: TrajectoryResult, prof: Profile) -> np.ndarray | None:
    """How far under a ripple crest each ice vertex lies, 0 to 1: where impure icicles hold
    their milky inclusions (Ladan & Morris 2022), for the renderer's shimmer.

    The crest's own height at the vertex (`carve_ripples`' displacement, without the fade
    where the mesh is too coarse to carry it: the inclusions are a look, not geometry) over
    the whole crest's depth; 0 in the troughs and off the icicles.

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices (ripples carved or not: they move across the axis only), meters.
    traj : TrajectoryResult
        The axes the ripples were carved around.
    prof : Profile
        `profile_args` of the surface group.

    Returns
    -------
    (n,) float32 or None
        None where there is no ripple (``amplitude`` 0, no branch).
    """
    waves = _waves(vertices, traj, prof, None)
    return None if waves is None else _bands(len(vertices), waves, prof.amplitude)


def _bands(n: int, waves: _Waves, amplitude: float) -> np.ndarray:
    """`ripple_bands` of ``n`` vertices from their `_Waves`."""
    bands = np.zeros(n, dtype=np.float32)
    bands[waves.near] = np.clip(waves.depth / amplitude * (BAND_FLOOR + (1 - BAND_FLOOR) * 0.5 * (1 + waves.crest)),
                                0.0, 1.0)
    return bands


@dataclass(frozen=True)
class _Waves:
    """The ripple at the vertices near the branches (k of them): their indices ``near``,
    the radial displacement ``wave`` (meters; faded where the mesh is too coarse to carry
    it), the offsets ``radial`` (k, 3) from the axis and their lengths ``dist``, the crest's
    local depth without that fade ``depth`` (meters) and where on the crest each lies,
    ``crest`` (-1 trough to 1 top)."""

    near: np.ndarray
    wave: np.ndarray
    radial: np.ndarray
    dist: np.ndarray
    depth: np.ndarray
    crest: np.ndarray


def _waves(vertices: np.ndarray, traj: TrajectoryResult, prof: Profile, max_radius: float | None) -> _Waves | None:
    """`_Waves` of ``vertices`` (n, 3), the fade to ``max_radius`` (`carve_ripples`) in the
    displacement only; None where there is no ripple."""
    amplitude, frequency, tip = prof.amplitude, prof.frequency, prof.tip
    branches = np.flatnonzero(np.diff(np.asarray(traj.branch_offsets)) > 0)
    if amplitude <= 0 or frequency <= 0 or len(branches) == 0 or len(vertices) == 0:
        return None
    x_pt, lengths = arc_lengths(traj.points, traj.branch_offsets)
    L = lengths[branches]
    grown = grown_lengths(L, traj.cut[branches])
    growth = traj.growth(prof.growth)[branches]
    step = min(2 * np.pi / frequency / SAMPLES_PER_WAVE, tip)
    n = np.ceil(L / step).astype(np.int64) + 1
    owner = np.repeat(np.arange(len(branches)), n)
    k = ragged_arange(n)
    x = k * (L / np.maximum(n - 1, 1))[owner]
    axis, tangent = points_along(traj, x_pt, lengths, branches[owner], x)
    radius = smooth_radius(x, grown[owner], replace(prof, growth=growth[owner]))
    # Natural ripples (`_texture`): a wandering wavelength, quiet above the tip, and crests
    # that tilt and fade around the trunk, each branch its own (seeded by its index: no
    # draw from the stage's stream).
    texture = _texture(branches, frequency, np.asarray(traj.branch_icicle)[branches])
    base = np.maximum(smooth_radius(0.0, grown[owner], replace(prof, growth=growth[owner])), ROOT_FADE * grown[owner])
    rise = np.clip(x / base, 0, 1)
    wave_amp = amplitude * texture.depth[owner] * _envelope(x, grown[owner], tip) * rise * rise * (3 - 2 * rise)
    wave_amp *= np.clip((radius - tip) / (RIPPLE_WIDENING * tip), 0, 1)
    carved = wave_amp if max_radius is None else wave_amp * np.clip((max_radius - radius) / (0.2 * max_radius), 0, 1)

    # Only where there is a ripple (not near tips or bases): the nearest axis sample there
    # carries an amplitude that fades in smoothly from the quiet stretches. The coarse parts
    # count (`carved` fades there): their milky bands stay, and a vertex follows its own
    # nearest sample, not a thinner one past the fade.
    rippled = np.flatnonzero(wave_amp > 0)
    if len(rippled) == 0:
        return None
    reach = REACH * radius[rippled].max() + amplitude
    lo, hi = axis[rippled].min(axis=0) - reach, axis[rippled].max(axis=0) + reach
    candidates = np.flatnonzero(within_box(vertices, lo, hi))
    phase, rate = _wandering_phase(x, owner, frequency, texture)
    samples = _Samples(point_index(axis[rippled]), rippled, reach, amplitude, axis, tangent, *_frames(tangent), x,
                       owner, L, radius, wave_amp, carved, phase, rate, texture,
                       _forks(branches, L, 2 * np.pi / frequency))
    # Each vertex's ripple is its own: chunks of them on every core (NumPy and the k-d
    # tree leave the GIL), joined in order, give the same arrays as one pass.
    threads = os.cpu_count() or 1
    chunks = np.array_split(candidates, threads) if len(candidates) >= _CHUNK * threads else [candidates]
    with ThreadPoolExecutor(len(chunks)) as pool:
        parts = list(pool.map(lambda c: _vertex_waves(vertices, c, samples), chunks))
    return _Waves(*(np.concatenate(arrays) for arrays in zip(*(vars(part).values() for part in parts))))


# Vertices a thread takes at least (`_waves`): fewer go in one pass.
_CHUNK = 20_000


@dataclass(frozen=True)
class _Samples:
    """The axis samples of `_waves` and what the ripple is there: the k-d tree of the
    ``rippled`` ones and how far from them (``reach``, m) a vertex may lie; per sample its
    point, tangent and frame, arc length ``x``, branch (``owner``), radius, wave amplitude
    (``carved``: faded where the mesh is coarse), phase and wavenumber; per branch its
    length, texture and forks."""

    tree: object
    rippled: np.ndarray
    reach: float
    amplitude: float
    axis: np.ndarray
    tangent: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    x: np.ndarray
    owner: np.ndarray
    lengths: np.ndarray
    radius: np.ndarray
    wave_amp: np.ndarray
    carved: np.ndarray
    phase: np.ndarray
    rate: np.ndarray
    texture: _Texture
    forks: _Forks


def _vertex_waves(vertices: np.ndarray, candidates: np.ndarray, s: _Samples) -> _Waves:
    """`_Waves` of the ``candidates`` (indices into ``vertices`` (n, 3)) near an axis."""
    _, i = nearest(s.tree, vertices[candidates], s.reach)
    found = i >= 0
    near, i = candidates[found], s.rippled[i[found]]
    t_i = s.tangent[i]  # gathered once: the gathers of (k, 3) rows are most of the cost here
    rel = vertices[near] - s.axis[i]
    along = np.einsum("ij,ij->i", rel, t_i)
    radial = rel - along[:, None] * t_i
    dist = np.linalg.norm(radial, axis=1)
    own = (dist <= REACH * s.radius[i] + s.amplitude) & (dist > 1e-9)
    i, radial, dist, along = i[own], radial[own], dist[own], along[own]
    b = s.owner[i]
    texture = s.texture
    # cos and sin of each vertex's angle around the axis, in its sample's frame
    cos_t = np.einsum("ij,ij->i", radial, s.e1[i]) / dist
    sin_t = np.einsum("ij,ij->i", radial, s.e2[i]) / dist
    x_i = s.x[i]
    xv = np.clip(x_i + along, 0.0, s.lengths[b])  # the vertex's own arc length along its branch
    # per branch, then gathered: the same numbers as per vertex, a fraction of the work
    tilt = cos_t * np.cos(texture.tilt_at)[b] + sin_t * np.sin(texture.tilt_at)[b]  # cos(theta - tilt_at)
    shift, core = _fork_shift(s.forks, b, xv, dist * cos_t, dist * sin_t)
    # the phase at the vertex: its sample's, carried on along the axis by the local wavenumber
    crest = np.sin(s.phase[i] + s.rate[i] * (xv - x_i) + texture.tilt[b] * tilt + shift)
    # crests fade and break around the circumference: an amplitude that drifts with angle
    # and with height, never below FADE_FLOOR of the full one
    swirl = texture.break_phase[b] + xv * texture.break_rate[b]
    fade = 0.5 * (1 + 2 * sin_t * cos_t * np.cos(swirl) + (cos_t**2 - sin_t**2) * np.sin(swirl))
    depth = (FADE_FLOOR + (1 - FADE_FLOOR) * fade) * core * _patches(texture, b, xv, cos_t, sin_t)
    return _Waves(near[own], s.carved[i] * crest * depth, radial, dist, s.wave_amp[i] * depth, crest)


# Natural ripples (Chen & Morris 2013; photographs of eaves icicles): the wavelength
# wanders by about WANDER (standard deviation of the local wavenumber, relative) over a few
# centimetres; crests tilt by up to TILT radians of phase around the trunk and fade to
# FADE_FLOOR of their depth on some sides; each icicle's ripples are deeper or shallower than
# the parameter says, within DEPTH_RANGE of it (neighbours on one eave differ: some near
# smooth, some ribbed); they rise from nothing at the root over ROOT_FADE of the icicle's length, and the
# last TIP_QUIET metres above the tip are smooth, rising to full depth over the next TIP_RISE.
# Uniform, steep crests read as a stack of glass coins whatever their texture (the bench's
# close-up view at 480 x 360, icicles 13 px wide): 1.1 mm crests with 1 rad of tilt refract
# the seat above into a zebra of dark stripes on every icicle alike. Nearly level, whole
# crests keep more of their depth in the radius measured around the trunk (a crest tilted by
# T keeps J0(T) of it), so the measure needs no steeper flanks for them; roots without
# ripples and a depth that differs from icicle to icicle break the curtain's regularity.
# Shallower still (0.5 mm crests) read better by eye, but the 0.3 m bunny's short icicles
# must keep 0.4 mm in the ripples' band: `surface.ripple_amplitude` 1.05 mm gives
# crests of 0.74 mm at the default impurity (0.44-0.85 by icicle), 0.41 mm on the bunny
# (relative storm) and 0.53 on one 12 cm icicle. WANDER stays this small because crests also fork
# (`FORK_SPACING`): both vary the crest spacing the measure reads, whose CV must stay under
# 0.35, and forks break the rings where wandering only spaces them unevenly.
WANDER = 0.15
WANDER_WAVES = (0.025, 0.04, 0.07)  # wavelengths (m) of the wandering's components
TILT = 0.5
FADE_FLOOR = 0.7
DEPTH_RANGE = (0.6, 1.15)
ROOT_FADE = 0.2
TIP_QUIET = 0.01
TIP_RISE = 0.03


# Crests fork (Chen & Morris 2013; photographs of eaves icicles): on part of the trunk one
# crest splits in two and the two merge again a little further round, which no wandering
# or tilt of whole rings gives. Every FORK_SPACING wavelengths or so along each branch
# (FORK_JITTER of that either way) a crest gains a neighbour over an arc of FORK_ARC radians
# (either way of it) around the trunk, centred at a random angle: a pair of dislocations
# in the ripple's phase at the arc's ends, each with a smooth core FORK_CORE wavelengths
# across; the new crest comes in over FORK_WIDTH wavelengths along the axis. It bends the
# crests within FORK_REACH wavelengths of it along the axis only, and the rest of the
# circumference keeps its crests: the radius measured around the trunk (its median) barely
# moves. Every 5 wavelengths with WANDER 0.15, ripple texture (depth mm, correlation, crest
# CV) at the defaults: bench 0.50, 0.22, 0.21; car 0.54, 0.22, 0.33; table 0.57, 0.21,
# 0.30 (WANDER 0.25, no forks: 0.54, -0.14, 0.22; 0.56, -0.14, 0.31; 0.60, -0.13, 0.28).
# Every 3.5 wavelengths the car's CV reaches 0.35. Every 8 because the ripples come in
# patches (`PATCH_FLOOR`): a calm stretch's crests fall under the measure's threshold and
# widen the gaps it reads (the fountain, relative storm, floor 0.3: CV 0.36 every 5, 0.30
# every 8).
FORK_SPACING = 8.0
FORK_JITTER = 0.25
FORK_REACH = 1.5
FORK_ARC = (0.6, 1.4)
FORK_CORE = 0.15
FORK_WIDTH = 0.5
FORK_MAX = 64  # per branch: 2.5 m of icicle at 1 cm ripples
FORK_SEED = RIPPLE_SEED + 1


@dataclass(frozen=True)
class _Forks:
    """Each branch's forks, laid end to end (``offsets``, (b + 1,)): arc length ``x`` (m,
    ascending per branch), ``key`` (x shifted by the branch's ``stride``, for one search),
    the arc's centre around the trunk (``cos``, ``sin``) and ``cos`` of its half-width
    (``edge``); ``reach``, ``core`` and ``width`` (m): `FORK_REACH`, `FORK_CORE` and
    `FORK_WIDTH` in meters."""

    offsets: np.ndarray
    x: np.ndarray
    key: np.ndarray
    stride: float
    cos: np.ndarray
    sin: np.ndarray
    edge: np.ndarray
    reach: float
    core: float
    width: float


def _forks(branches: np.ndarray, lengths: np.ndarray, wavelength: float) -> _Forks:
    """The forks of ``branches`` (their indices in the trajectories, which seed their draws)
    of ``lengths`` (m), for ripples ``wavelength`` (m) apart."""
    spacing = FORK_SPACING * wavelength
    count = np.minimum(np.floor(lengths / spacing).astype(np.int64) + 1, FORK_MAX)
    # row b is branch b's draws whatever the table's length, as in `_texture`
    draws = np.random.default_rng(FORK_SEED).random((int(branches.max(initial=-1)) + 1, FORK_MAX, 3))[branches]
    owner = np.repeat(np.arange(len(branches)), count)
    j = ragged_arange(count)
    d = draws[owner, j]
    x = (j + 0.5 + FORK_JITTER * (2 * d[:, 0] - 1)) * spacing
    stride = float(lengths.max(initial=0.0)) + 2 * spacing
    centre = 2 * np.pi * d[:, 1]
    return _Forks(offsets=np.concatenate([[0], np.cumsum(count)]), x=x, key=owner * stride + x, stride=stride,
                  cos=np.cos(centre), sin=np.sin(centre),
                  edge=np.cos(FORK_ARC[0] + (FORK_ARC[1] - FORK_ARC[0]) * d[:, 2]),
                  reach=FORK_REACH * wavelength, core=FORK_CORE * wavelength, width=FORK_WIDTH * wavelength)


def _fork_shift(forks: _Forks, b: np.ndarray, x: np.ndarray, u: np.ndarray, v: np.ndarray):
    """The forks' shift of the ripple's phase (rad) at points of branches ``b`` at arc length
    ``x`` and ``(u, v)`` (m) across the axis, and the factor (0-1) that smooths each core.

    With ``y = width (cos(a - ac) - cos(w)) / (1 - cos(w))`` (``width`` at the arc's centre
    ``ac``, 0 at its ends ``ac +- w``, negative off it) and ``X`` the arc length past the
    fork, a fork adds ``atan2(y g, -X) + pi - atan2(l g, X)`` (``g`` 1 at the fork, 0 from
    ``reach`` on; ``l`` the typical ``-y`` off the arc): 0 on the root side, 2 pi on the
    arc's tip side (one crest more), about 0 off the arc. The forks are at least ``reach``
    apart, so only the nearest on either side counts, and only within ``reach`` of it.
    """
    above = np.searchsorted(forks.key, b * forks.stride + x)  # the first fork tipwards
    shift = np.zeros(len(x))
    core = np.ones(len(x))
    for k, valid in ((above - 1, above > forks.offsets[b]), (above, above < forks.offsets[b + 1])):
        i = np.flatnonzero(valid)
        k = k[i]
        along = x[i] - forks.x[k]
        near = np.abs(along) < forks.reach
        i, k, along = i[near], k[near], along[near]
        edge = forks.edge[k]
        y = forks.width * ((u[i] * forks.cos[k] + v[i] * forks.sin[k]) / np.hypot(u[i], v[i]) - edge) / (1 - edge)
        typical = 0.5 * forks.width * (1 + edge) / (1 - edge)
        g = (1 - (along / forks.reach) ** 2) ** 2
        shift[i] += np.arctan2(y * g, -along) + np.pi - np.arctan2(typical * g, along)
        r2 = along**2 + y**2
        core[i] *= np.sqrt(r2 / (r2 + g * forks.core**2))
    return shift, core


# Patches (photographs of eaves and fence icicles): ripples run deep on some stretches and
# sides of a trunk and nearly vanish on others, a few centimetres apart; uniform rings, each
# as deep as the last all round, read as a screw thread or a stack of glass coins up close
# (the bench's and the car's ice views). Along each branch the depth swells and ebbs between
# PATCH_FLOOR and 1 (times PATCH_GAIN) over PATCH_WAVES (m), the swell's phase leaning
# PATCH_TWIST radians around the trunk, so a patch covers one side of a few crests, not
# whole rings. The gain keeps the ripple's mean square about what it is without patches, so the
# measured depth stays at least 0.4 mm (relative storm, spectral amplitude / texture
# depth / crest CV: bunny 0.407 / 0.637 / 0.14 mm without patches, 0.445 / 0.651 / 0.13 with
# them; fountain 0.421 / 0.535 / 0.28, 0.460 / 0.524 / 0.24; at the defaults, car 0.428 /
# 0.543 / 0.33, 0.444 / 0.554 / 0.34). A calmer floor, 0.3 with a gain of 1.5, puts the car's
# crest CV at 0.36, over the natural 0.35 (its calm stretches' crests fall under the
# measure's threshold); 0.15 with no gain reads better still on the bench, but measures
# 0.27 mm on one 12 cm icicle.
PATCH_FLOOR = 0.4
PATCH_GAIN = 1.4
PATCH_WAVES = (0.035, 0.06)
PATCH_TWIST = 0.8
PATCH_SEED = RIPPLE_SEED + 2


def _patches(texture: _Texture, b: np.ndarray, x: np.ndarray, cos_t: np.ndarray, sin_t: np.ndarray) -> np.ndarray:
    """Depth factor (`PATCH_FLOOR` to 1) of the ripples at points of branches ``b`` at arc
    length ``x`` (m) and angle ``(cos_t, sin_t)`` around the trunk."""
    q = 2 * np.pi / np.asarray(PATCH_WAVES)
    swell = np.zeros(len(x))
    for k in range(len(q)):
        lean = cos_t * np.cos(texture.patch_at[b, k]) + sin_t * np.sin(texture.patch_at[b, k])
        swell += np.sin(q[k] * x + texture.patch_phase[b, k] + PATCH_TWIST * lean)
    t = np.clip(0.5 + swell / (2 * len(q)) * 1.6, 0.0, 1.0)
    return PATCH_GAIN * (PATCH_FLOOR + (1 - PATCH_FLOOR) * t * t * (3 - 2 * t))


@dataclass(frozen=True)
class _Texture:
    """Per branch: the wandering's phases, the crests' tilt and where it leans, how their
    depth breaks around the trunk."""

    wander_phase: np.ndarray  # (b, len(WANDER_WAVES))
    tilt: np.ndarray
    tilt_at: np.ndarray
    break_phase: np.ndarray
    break_rate: np.ndarray
    phase0: np.ndarray
    depth: np.ndarray  # its icicle's ripple depth over the parameter's, within DEPTH_RANGE
    patch_phase: np.ndarray  # (b, len(PATCH_WAVES)): `_patches`
    patch_at: np.ndarray


def _texture(branches: np.ndarray, frequency: float, icicles: np.ndarray) -> _Texture:
    k = len(WANDER_WAVES)
    # row b of one table is branch b's draws whatever the table's length (rows come in order)
    table = np.random.default_rng(RIPPLE_SEED).random((int(branches.max(initial=-1)) + 1, k + 5))
    draws = table[branches]
    # One depth per icicle (its branches alike), spread evenly over any run of icicles (a
    # golden-ratio sequence: neighbours differ), most near full depth; icicle 0 gets the median.
    u = (0.5 + icicles * (GOLDEN_ANGLE / (2 * np.pi))) % 1.0
    two_pi = 2 * np.pi
    m = len(PATCH_WAVES)
    patch = np.random.default_rng(PATCH_SEED).random((int(branches.max(initial=-1)) + 1, 2 * m))[branches]
    return _Texture(patch_phase=two_pi * patch[:, :m], patch_at=two_pi * patch[:, m:],
                    wander_phase=two_pi * draws[:, :k], tilt=TILT * (0.4 + 0.6 * draws[:, k]),
                    tilt_at=two_pi * draws[:, k + 1], break_phase=two_pi * draws[:, k + 2],
                    break_rate=(20.0 + 40.0 * draws[:, k + 3]) * (1 if frequency > 0 else 0),
                    phase0=(branches * GOLDEN_ANGLE + two_pi * draws[:, k + 4]) % two_pi,
                    depth=DEPTH_RANGE[1] - (DEPTH_RANGE[1] - DEPTH_RANGE[0]) * u**2)


def _wandering_phase(x: np.ndarray, owner: np.ndarray, frequency: float,
                     texture: _Texture) -> tuple[np.ndarray, np.ndarray]:
    """The ripple's phase at arc lengths ``x`` of branches ``owner``, and its derivative (the
    local wavenumber, rad/m): ``frequency x`` plus the integral of a wavenumber that wanders
    by `WANDER` (a sum of slow sines, `WANDER_WAVES`)."""
    q = 2 * np.pi / np.asarray(WANDER_WAVES)  # (k,)
    weight = WANDER * np.sqrt(2.0 / len(q))
    angle = q[None, :] * x[:, None] + texture.wander_phase[owner]  # (n, k)
    integral = ((np.cos(texture.wander_phase[owner]) - np.cos(angle)) / q[None, :]).sum(axis=1)
    phase = frequency * (x + weight * integral) + texture.phase0[owner]
    return phase, frequency * (1.0 + weight * np.sin(angle).sum(axis=1))


def _envelope(x: np.ndarray, length: np.ndarray, tip: float) -> np.ndarray:
    """Depth of the ripples along a branch, 0 to 1: none over the last `TIP_QUIET` above
    the tip (and at least `TIP_CALM` tip radii), rising smoothly over `TIP_RISE`."""
    from_tip = np.maximum(np.asarray(length, dtype=np.float64) - x, 0.0)
    quiet = max(TIP_QUIET, TIP_CALM * tip)
    t = np.clip((from_tip - quiet) / TIP_RISE, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _frames(tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across each unit ``tangent`` (m, 3), turning with it: the angle
    around the axis is measured from the first (world x, or world z for a tangent along x)."""
    ref = np.where(np.abs(tangent[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    e1 = ref - np.einsum("ij,ij->i", ref, tangent)[:, None] * tangent
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(tangent, e1)
