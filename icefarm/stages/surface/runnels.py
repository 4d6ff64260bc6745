"""Glaze that froze as it flowed: runnels and frozen drops on sloped and vertical faces.

Freezing rain does not set as an even varnish where it runs: the film gathers into rivulets
that freeze into ridges along the slope, a centimetre or two apart, and into beads where
their drops stop. A level top stays smooth (its water stands or spreads). Here the coat's
face is carved after marching (`carve_runnels`: per vertex, smooth at the voxel; scaling
the thickness the coat's field is built from tears its two-voxel samples into shards): its
height over the object is scaled by a relief that runs down the slope: a sum of
waves across the downhill direction (the rivulets), switched on and off along it (they start
and stop), sharpened into ridges, with beads strung along them; the share of it grows with
the face's steepness. Its mean over the steep samples is 1, so the ice's volume stays.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ...geometry import perpendicular_basis, unit
from .smooth import CLEAR, CoatVertices

# Rivulets' spacing across the slope (m): freezing-rain runnels on walls and rails run a
# centimetre or two apart, a few merge into wider ones.
RUNNEL_WAVELENGTHS = (0.017, 0.023, 0.031, 0.043)
# How long a rivulet runs before it stops (m), and how far apart its frozen drops sit.
RUN_LENGTH = 0.12
BEAD_SPACING = 0.018
# Ridge sharpness: the rivulets' relief is exp(RIDGE_GAIN x their waves) (0: none; higher:
# narrow ridges, thin ice between).
RIDGE_GAIN = 0.9
# Beads add this much of a ridge's height where they sit.
BEAD_GAIN = 0.8
# The relief keeps the coat between these shares of its thickness: deeper, the coat's
# lattice (4-6 mm voxels) breaks it into shards.
FLOOR = 0.4
PEAK = 1.8


def runnel_relief(points: np.ndarray, normals: np.ndarray, gravity, amplitude: float,
                  rng: np.random.Generator) -> np.ndarray:
    """``(k,)`` factors on the coat's thickness at surface ``points`` (k, 3) of unit outward
    ``normals`` (k, 3): runnels and beads down sloped and vertical faces, 1 on level ones.

    Parameters
    ----------
    points, normals : (k, 3) float
        Meters; unit vectors.
    gravity : (3,) float
    amplitude : float
        ``glaze.runnels``, 0 to 1: the relief's share of the thickness on a vertical face
        (0: every factor is 1).
    rng : numpy.random.Generator
        The waves' phases and the beads' offsets.

    Returns
    -------
    (k,) float
        Between `FLOOR` and `PEAK`; about 1 on average over the samples that slope.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    k = len(points)
    phases = rng.random((len(RUNNEL_WAVELENGTHS), 4)) * 2.0 * np.pi
    if k == 0 or amplitude <= 0:
        return np.ones(k)
    g = unit(np.asarray(gravity, dtype=np.float64).reshape(3))
    steep = np.sqrt(np.clip(1.0 - (normals @ g) ** 2, 0.0, 1.0))  # 0 on a level face, 1 on a vertical one
    # Waves across level directions, the same all the way down: on a wall they are streaks
    # down it, on a slope the vertical projection of the same pattern (longer the steeper).
    # Local frames (across each normal's slope) turn too fast on a curved object: the
    # bunny's coat comes out furred.
    e1, e2 = perpendicular_basis(g)
    v = points @ g  # down the slope
    waves = np.zeros(k)
    beads = np.zeros(k)
    for (wavelength, (a, b, c, turn)) in zip(RUNNEL_WAVELENGTHS, phases):
        u = points @ (np.cos(turn) * e1 + np.sin(turn) * e2)
        rivulet = np.cos(2.0 * np.pi * u / wavelength + a)
        runs = 0.5 + 0.5 * np.cos(2.0 * np.pi * v / RUN_LENGTH + b + 3.0 * np.sin(2.0 * np.pi * u / (5 * wavelength)))
        waves += rivulet * runs
        beads = np.maximum(beads, np.clip(np.cos(2.0 * np.pi * v / BEAD_SPACING + c + 7.0 * u / wavelength), 0.0, 1.0)
                           ** 6 * (rivulet > 0.6))
    # Ridges: the waves' sum (standard deviation 1) through an exponential, so the film
    # gathers into rivulets with thin ice between, never a hole.
    ridge = np.exp(RIDGE_GAIN * waves / np.sqrt(0.5 * len(RUNNEL_WAVELENGTHS)))
    relief = ridge * (1.0 + BEAD_GAIN * beads)
    weight = np.clip(steep, 0.0, 1.0) ** 1.5
    sloped = weight > 0.05
    if not sloped.any():
        return np.ones(k)
    factor = np.clip(1.0 + amplitude * weight * (relief / np.average(relief[sloped], weights=weight[sloped]) - 1.0),
                     FLOOR, PEAK)
    # The clipping took off more above than below: scale the relief's part back to a mean of 1.
    dev = factor - 1.0
    excess = float(np.average(dev[sloped], weights=weight[sloped]))
    return np.clip(1.0 + dev - excess * weight / np.average(weight[sloped], weights=weight[sloped]), FLOOR, PEAK)


def carve_runnels(vertices: np.ndarray, coat: CoatVertices, surface: trimesh.Trimesh, gravity, amplitude: float,
                  voxel: float, rng: np.random.Generator) -> np.ndarray:
    """The ice mesh with runnels and frozen drops carved into the glaze coat's face.

    Each vertex of the coat's outer face (`icefarm.stages.surface.smooth.coat_vertices`)
    moves along the normal of the covered surface at its nearest vertex so that its height
    over it is `runnel_relief` times what it was; none comes closer than
    `icefarm.stages.surface.smooth.CLEAR` voxels to the object (one already closer only
    rises).

    Parameters
    ----------
    vertices : (n, 3) float
        Ice mesh vertices, meters.
    coat : CoatVertices
    surface : trimesh.Trimesh
        What the coat covers.
    gravity : (3,) float
    amplitude : float
        ``glaze.runnels`` (0 returns ``vertices``).
    voxel : float
        The coat's voxel, meters.
    rng : numpy.random.Generator

    Returns
    -------
    (n, 3) float64
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    outer = np.flatnonzero(coat.outer)
    if amplitude <= 0 or len(outer) == 0:
        return vertices
    normals = np.asarray(surface.vertex_normals)[coat.near[outer]]
    height = coat.height[outer]
    factor = runnel_relief(vertices[outer], normals, gravity, amplitude, rng)
    # A coat thinner than CLEAR voxels only gains its ridges: it never comes nearer the object.
    move = np.maximum((factor - 1.0) * height, np.minimum(CLEAR * voxel - height, 0.0))
    out = vertices.copy()
    out[outer] += move[:, None] * normals
    return out
