"""Gaussian metaballs and their calibration: chains that make tubes, sheets that make coats.

Gaussian balls (Blinn's blobby model; why Gaussian: `icefarm.metaballs.field`).
Calibration (module constants below):

* chain of balls of radius R: width ``s = KAPPA * R``, spacing ``SPACING * s``; the
  line integral ``(sqrt(pi) s / h) exp(-rho^2 / s^2)`` of a dense chain equals
  ``LEVEL`` at ``rho = R`` exactly, so a straight chain's surface sits at R
  (bumps between balls stay below 0.1 % of R); the last ball of a branch weighs
  ``TIP_WEIGHT`` so the end of the chain is a hemisphere of radius R(L) (within 2 %);
* sheet balls (the glaze's ``metaballs`` mode) of radius r, one per area A: width
  ``max(SHEET_KAPPA * r, SHEET_OVERLAP * sqrt(A))`` and a weight that makes the sheet
  they form r thick on each side of the surface (a plane of balls integrates to
  ``pi s^2 / A exp(-z^2 / s^2)``), so Equations 2 and 3 give ice thickness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Chain calibration (see the module docstring): width/radius, spacing/width, tip weight.
KAPPA = 0.6
SPACING = 1.2
TIP_WEIGHT = 1.4
# Iso level of the field: a dense straight chain of unit-weight balls crosses it at R.
LEVEL = math.sqrt(math.pi) / SPACING * math.exp(-1.0 / KAPPA**2)
# Width/thickness of base and glaze balls, and their least width per ball spacing
# (sqrt of the area per ball): about pi * 2^2 = 12 balls overlap at each point of a sheet.
SHEET_KAPPA = 1.0
SHEET_OVERLAP = 2.0


@dataclass(frozen=True)
class Balls:
    """Gaussian metaballs ``weight * exp(-|p - center|^2 / width^2)``.

    Attributes
    ----------
    centers : (n, 3) float64
        In meters.
    widths : (n,) float64
        Gaussian width ``s``, in meters.
    weights : (n,) float64
        Peak value of each ball.
    """

    centers: np.ndarray
    widths: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return len(self.widths)


def concat_balls(*parts: Balls) -> Balls:
    """All balls of ``parts`` in one `Balls`."""
    return Balls(
        np.concatenate([p.centers for p in parts]).reshape(-1, 3),
        np.concatenate([p.widths for p in parts]),
        np.concatenate([p.weights for p in parts]),
    )


NO_BALLS = Balls(np.zeros((0, 3)), np.zeros(0), np.zeros(0))


def sheet_balls(centers: np.ndarray, thickness: np.ndarray, area_per_ball: np.ndarray | float) -> Balls:
    """Balls on a surface that together make a sheet ``thickness`` thick on each side.

    A plane of Gaussian balls of width s and weight w, one per area A, has the field
    ``w pi s^2 / A exp(-z^2 / s^2)`` at height z: the weight puts ``LEVEL`` at
    ``z = thickness``. The width is ``SHEET_KAPPA * thickness`` but at least
    ``SHEET_OVERLAP * sqrt(A)``, so each point of the surface sees about a dozen balls and
    the sheet stays continuous, down to nothing where the thickness goes to zero.

    Parameters
    ----------
    centers : (k, 3) float
        On the surface, in meters.
    thickness : (k,) float
        Ice thickness over the surface at each ball (Equation 2's rb, Equation 3's rgi), in
        meters.
    area_per_ball : float or (k,) float
        Surface area per ball where they lie, in square meters.
    """
    thickness = np.maximum(np.asarray(thickness, dtype=np.float64), 0.0)
    area = np.broadcast_to(np.asarray(area_per_ball, dtype=np.float64), thickness.shape)
    width = np.maximum(SHEET_KAPPA * thickness, SHEET_OVERLAP * np.sqrt(area))
    weight = LEVEL * area / (math.pi * width**2) * np.exp((thickness / np.maximum(width, 1e-300)) ** 2)
    return Balls(np.asarray(centers, dtype=np.float64).reshape(-1, 3), width, weight)
