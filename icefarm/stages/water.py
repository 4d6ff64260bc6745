"""Stage 1 (paper 4.1): the water supply from rain rays and Algorithm 1's water coefficients."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..geometry import chain_sums, perpendicular_basis, sample_faces, unit
from ..spatial import ray_caster
from ..tol import tol
from .basins import overflow_heights


@dataclass(frozen=True)
class WaterResult:
    """Water on the surface stages 1-2 run on, per vertex.

    Attributes
    ----------
    supply : (n,) bool
        Vertex is in the water supply (reached by rain, facing up, not occluded).
    water : (n,) float
        Water coefficient wc of Algorithm 1, in meters (height climbed through wet edges;
        with ``pools="overflow"``, plus the depth of a basin spilling where the walk ends).
    top : (n,) int
        Highest vertex reached by the upward walk.
    d_up : (n,) float
        Distance walked up to ``top``, in meters (dUp of Equation 3).
    bottom : (n,) int
        Lowest vertex reached by the downward walk (where the water ends: it drips or pools).
    d_down : (n,) float
        Distance walked down to ``bottom``, in meters (dDown of Equation 3).
    hits : (k, 3) float
        Rain hit points on the surface, in meters.
    storm : StormResult or None
        ``storm.mode: physical``: the storm's catch, glaze and shed water per vertex
        (`icefarm.stages.storm`); None in the relative mode.
    """

    supply: np.ndarray
    water: np.ndarray
    top: np.ndarray
    d_up: np.ndarray
    bottom: np.ndarray
    d_down: np.ndarray
    hits: np.ndarray
    storm: Any = None


def rain_source(mesh: trimesh.Trimesh, gravity: np.ndarray, margin: float = 0.05) -> trimesh.Trimesh:
    """The default source surface: a rectangle above the object, facing along gravity.

    It covers the object's shadow along gravity with ``margin`` (a fraction of the
    largest extent) to spare, and lies that far above the object's highest point.
    """
    g = unit(gravity)
    u, v = perpendicular_basis(g)
    pu, pv, pg = mesh.vertices @ u, mesh.vertices @ v, mesh.vertices @ g
    pad = margin * float(np.ptp(mesh.vertices, axis=0).max())
    us = [pu.min() - pad, pu.max() + pad]
    vs = [pv.min() - pad, pv.max() + pad]
    height = pg.min() - pad
    corners = np.array([a * u + b * v + height * g for a, b in ((us[0], vs[0]), (us[1], vs[0]),
                                                                   (us[1], vs[1]), (us[0], vs[1]))])
    return trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)


def water_supply(mesh: trimesh.Trimesh, gravity: np.ndarray, rays: int, influence_radius: float,
                 rng: np.random.Generator, source: trimesh.Trimesh | None = None,
                 caster=None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices reached by rain: the water supply of paper 4.1.

    ``rays`` rain rays leave random points of ``source`` along gravity. Every vertex that
    lies within ``influence_radius`` of a first hit, faces against gravity and sees the sky
    straight up (nothing of the object above it) joins the supply.

    ``caster`` is a `icefarm.spatial.ray_caster` of ``mesh`` to reuse, if one exists.

    Returns
    -------
    supply : (n,) bool
    hits : (k, 3) float
        First hits of the rays on the mesh, in meters.
    """
    g = unit(gravity)
    source = rain_source(mesh, g) if source is None else source
    origins, _, _ = sample_faces(source, np.arange(len(source.faces)), rays, rng)
    cast = caster or ray_caster(mesh)
    directions = np.broadcast_to(g, origins.shape)
    distance, _ = cast(origins, directions)
    landed = np.isfinite(distance)
    hits = origins[landed] + distance[landed, None] * g
    supply = np.zeros(len(mesh.vertices), dtype=bool)
    if len(hits) == 0:
        return supply, hits.reshape(-1, 3)
    distance, _ = cKDTree(hits).query(mesh.vertices, distance_upper_bound=influence_radius)
    candidates = np.flatnonzero((distance <= influence_radius) & (mesh.vertex_normals @ g < 0))
    # A vertex near a hit on an overhang above it is still in the overhang's shadow.
    eps = tol.hair * float(np.linalg.norm(mesh.extents))
    lifted = mesh.vertices[candidates] - eps * g + eps * mesh.vertex_normals[candidates]
    shadowed = np.isfinite(cast(lifted, np.broadcast_to(-g, lifted.shape))[0])
    supply[candidates[~shadowed]] = True
    return supply, hits


def steepest_neighbours(mesh: trimesh.Trimesh, gravity: np.ndarray) -> tuple[tuple, tuple]:
    """Each vertex's most upward and most downward edge neighbour.

    Returns
    -------
    up, down : tuple of (nxt, p, length), each ``(n,)``
        ``nxt``: the chosen neighbour, the vertex itself where none is higher (lower);
        ``p``: dot(unit edge vector, g) of that edge; ``length``: its length in meters
        (both 0 at chain ends).
    """
    edges = mesh.edges_unique
    length = mesh.edges_unique_length
    p = ((mesh.vertices[edges[:, 1]] - mesh.vertices[edges[:, 0]]) @ unit(gravity)) / np.where(length > 0, length, 1)
    n = len(mesh.vertices)
    # Directed edges a -> b; a key of vertex + p in [0, 1) sorts by vertex, then by steepness.
    a = np.concatenate([edges[:, 0], edges[:, 1]])
    b = np.concatenate([edges[:, 1], edges[:, 0]])
    p2, length2 = np.concatenate([p, -p]), np.concatenate([length, length])
    result = []
    for sign in (1.0, -1.0):  # upward: most negative p first; downward: most positive first
        keep = sign * p2 < 0
        ka, kb, kp, kl = a[keep], b[keep], p2[keep], length2[keep]
        order = np.argsort(ka + 0.5 * (1.0 + sign * kp), kind="stable")
        ka, kb, kp, kl = ka[order], kb[order], kp[order], kl[order]
        first = np.flatnonzero(np.r_[True, ka[1:] != ka[:-1]]) if len(ka) else np.zeros(0, dtype=np.int64)
        nxt, best_p, best_len = np.arange(n), np.zeros(n), np.zeros(n)
        nxt[ka[first]], best_p[ka[first]], best_len[ka[first]] = kb[first], kp[first], kl[first]
        result.append((nxt, best_p, best_len))
    return result[0], result[1]


def water_coefficients(mesh: trimesh.Trimesh, supply: np.ndarray, gravity: np.ndarray):
    """Algorithm 1, with all upward walks advancing together.

    From every vertex the walk follows the most upward neighbour while one exists, adding
    ``d * (-p)`` for each edge with a supply vertex at either end, halved when only one end
    is in the supply. Downward walks (most downward neighbour) give dDown.

    Returns
    -------
    water, top, d_up, bottom, d_down : (n,) arrays
        See `WaterResult`.
    """
    supply = np.asarray(supply, dtype=bool)
    (up, p, length), (down, _, down_length) = steepest_neighbours(mesh, gravity)
    wet_ends = supply.astype(np.float64) + supply[up]
    gain = length * -p * np.where(wet_ends == 2, 1.0, 0.5 * wet_ends)
    sums, top = chain_sums(up, np.column_stack([gain, length]))
    d_down, bottom = chain_sums(down, down_length[:, None])
    return sums[:, 0], top, sums[:, 1], bottom, d_down[:, 0]


@dataclass(frozen=True)
class RainOptions:
    """How stage 1 rains on the object: the ``water`` group's rays, radius and pools.

    Attributes
    ----------
    rays : int
        Rain rays (nr).
    influence_radius : float
        rii, in meters.
    pools : {"ignore", "overflow"}
        ``overflow`` adds what full basins spill (`overflow_heights`) to the water of
        every vertex whose upward walk ends on a rim; ``ignore`` is Algorithm 1 as published.
    """

    rays: int
    influence_radius: float
    pools: str = "ignore"


def compute_water(mesh: trimesh.Trimesh, gravity, rain: RainOptions, rng: np.random.Generator,
                  source: trimesh.Trimesh | None = None, caster=None) -> WaterResult:
    """Stage 1: the water supply and the water coefficients of every vertex.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface the water flows on, in meters.
    gravity : (3,) float
        Direction of gravity.
    rain : RainOptions
        Rays, their radius of influence and what pools do.
    rng : numpy.random.Generator
    source : trimesh.Trimesh, optional
        Source surface ss; by default a rectangle above the object (`rain_source`).
    caster : callable, optional
        A `icefarm.spatial.ray_caster` of ``mesh``, shared with later stages.
    """
    g = unit(gravity)
    if not np.any(g):
        raise ValueError("gravity must not be the zero vector")
    caster = caster or ray_caster(mesh)
    supply, hits = water_supply(mesh, g, rain.rays, rain.influence_radius, rng, source, caster)
    water, top, d_up, bottom, d_down = water_coefficients(mesh, supply, g)
    if rain.pools == "overflow":
        water = water + overflow_heights(mesh, supply, g, caster)[top]
    return WaterResult(supply=supply, water=water, top=top, d_up=d_up,
                       bottom=bottom, d_down=d_down, hits=hits)
