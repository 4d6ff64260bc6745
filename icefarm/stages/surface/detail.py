"""A geometric-error budget for the icicles: thick parts on a coarse lattice, thin ends fine.

One marching-cubes lattice must resolve the thinnest tip (a chain narrower than about two
voxels breaks into beads), so on a big asset one lattice meshes every square centimetre of a
5 cm thick icicle at the tip's 2.4 mm: the 3 m house's icicles make 7.2 M faces. Marching a
surface of radius r at voxel h misses it by about ``h^2 / (8 r)``; a ball of radius at least
h therefore stays within ``h / 8`` of its exact surface. So the icicles' balls at least
`COARSE` times the fine voxel in radius go to a lattice that much coarser, the thinner ones
(tips, thin branches) keep the fine one, and `icefarm.metaballs.fuse_fields` unites the two
where they overlap.

The budget is a distance on screen: ``surface.error_px``, in pixels of a view `VIEW_PX`
pixels wide framing the object's bounding box. Both budgets are set for lookdev
(`VIEW_PX` x `VIEW_PX_HIGH` with an ice view, which zooms `ICE_ZOOM` times or more onto the
icicles). A job whose views show less (a preview: 320 x 240, the whole object only) meshes
so that its picture shows faces and error the size lookdev's ice view shows them
(`view_surface`). The coarse lattice is used only where
that allows it (``8 error >= COARSE * fine voxel``) and where ripples are below the
error or still resolved (`RIPPLE_SAMPLES` samples per wavelength): a 0.3 m bunny keeps one
lattice; the 3 m house (pixel 11 mm) meshes its icicles' thick parts at 3 times the tip's
voxel.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ...metaballs import Balls
from ...metaballs.balls import KAPPA
from ...tol import tol

# Coarse voxel / fine voxel, when the budget allows a coarse lattice at all.
COARSE = 3.0
# The view the error and face budgets are set for (lookdev's), pixels.
VIEW_PX = 480
VIEW_PX_HIGH = 360
# An ice view is at least this much closer than a view of the whole object of its size
# (`icefarm.scene.focus.MIN_ZOOM`).
ICE_ZOOM = 2.5
# Least lattice samples per ripple wavelength on the coarse lattice, when the ripples are
# deeper than the error budget.
RIPPLE_SAMPLES = 4
# Balls from 1 to this many coarse voxels in radius are on both lattices: the two surfaces
# overlap where they meet.
BAND = 1.2


def coarse_voxel(fine_voxel: float, extent: float, error_px: float, ripple_amplitude: float,
                 ripple_wavelength: float) -> float | None:
    """The coarse lattice's voxel (meters), or None when one lattice is as good.

    Parameters
    ----------
    fine_voxel : float
        The icicles' voxel (resolves the tips), meters.
    extent : float
        Diagonal of the object's bounding box, meters: a `VIEW_PX` wide view frames it.
    error_px : float
        The budget: most distance (pixels of that view) the mesh may lie off its surface;
        0 turns the coarse lattice off.
    ripple_amplitude, ripple_wavelength : float
        The ripples carved afterwards, meters (amplitude 0: none).
    """
    if error_px <= 0 or fine_voxel <= 0:
        return None
    error = error_px * extent / VIEW_PX
    voxel = min(8.0 * error, COARSE * fine_voxel)
    if ripple_amplitude > error and ripple_wavelength > 0:
        voxel = min(voxel, ripple_wavelength / RIPPLE_SAMPLES)
    return voxel if voxel >= COARSE * fine_voxel * (1 - tol.slack) else None


@dataclass(frozen=True)
class MeshingView:
    """The view a job's ice is meshed for: its render config's size, and whether it has an
    ice view (lookdev's budgets are set for lookdev's ice view, a zoom on the icicles).

    Attributes
    ----------
    width, height : int
        Pixels.
    ice_view : bool
        One of its views frames the ice (and shows the mesh `ICE_ZOOM` or more times larger
        than a view of the whole object of that size).
    """

    width: int
    height: int
    ice_view: bool

    @property
    def share(self) -> float:
        """Share of lookdev's detail this view shows, at most 1: its pixels over lookdev's,
        over `ICE_ZOOM` squared without an ice view."""
        pixels = self.width * self.height / (1.0 if self.ice_view else ICE_ZOOM ** 2)
        return min(1.0, pixels / (VIEW_PX * VIEW_PX_HIGH))


def meshing_view(resolution: tuple[int, int] | None, ice_view: bool = False) -> MeshingView:
    """The view a render config of ``resolution`` (width, height pixels) shows the ice in,
    with an ice view or not; no render (None) is meshed for lookdev's."""
    if resolution is None:
        return MeshingView(VIEW_PX, VIEW_PX_HIGH, True)
    width, height = (int(v) for v in resolution)
    return MeshingView(width, height, bool(ice_view))


def view_surface(surface, view: MeshingView):
    """``surface`` (the resolved ``surface`` group) with its budgets for ``view``: a view
    showing less detail than lookdev's (`MeshingView.share` under 1) scales ``face_budget``
    by its share and ``error_px`` (pixels of a `VIEW_PX` wide view of the whole object) by
    the inverse square root, so that its picture shows the mesh's faces and error the size
    lookdev's ice view shows them. ``error_px`` 0 and ``face_budget`` 0 (off) stay 0; other
    views keep the budgets as set.
    """
    share = view.share
    if share >= 1.0:
        return surface
    return dataclasses.replace(surface, face_budget=int(round(surface.face_budget * share)),
                               error_px=surface.error_px / math.sqrt(share))


def split_balls(balls: Balls, voxel: float, surface_points: np.ndarray, clearance: float,
                chain: np.ndarray | None = None) -> tuple[Balls, Balls]:
    """``(coarse, fine)``: the balls the ``voxel`` lattice resolves, and the thin rest.

    A ball goes to the fine lattice when its radius (width / `KAPPA` for a chain ball) is
    under `BAND` ``voxel`` and it lies farther than ``clearance`` plus its reach from every
    ``surface_points`` (the glaze coat is united with the coarse part first and must stay
    out of the fine part's way). Balls from 1 to `BAND` ``voxel`` in radius go to both, so
    the two surfaces overlap where they meet.

    Parameters
    ----------
    balls : Balls
    voxel : float
        The coarse voxel, meters.
    surface_points : (n, 3) float
        Points of the surface the coat lies on, meters.
    clearance : float
        Least distance from those points of any fine ball's reach, meters.
    chain : (len(balls),) bool, optional
        Which balls are chain balls (icicles); the others (bases, curtains, mounds) stay
        on the coarse lattice. Default: all are.

    Returns
    -------
    coarse, fine : Balls
    """
    radius = balls.widths / KAPPA
    thin = radius < BAND * voxel
    if chain is not None:
        thin &= np.asarray(chain, dtype=bool)
    if thin.any() and len(surface_points):
        reach = 3.0 * balls.widths[thin]  # the Gaussian is below 1e-4 of its peak past 3 widths
        d, _ = cKDTree(surface_points).query(balls.centers[thin])
        idx = np.flatnonzero(thin)
        thin[idx[d < clearance + reach]] = False
    fine = thin
    coarse = ~thin | (radius >= voxel)
    return _take(balls, coarse), _take(balls, fine)


def _take(balls: Balls, keep: np.ndarray) -> Balls:
    return Balls(balls.centers[keep], balls.widths[keep], balls.weights[keep])


def surface_spacing(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The longest edge of a mesh, meters: how far a point of it may be from its vertices."""
    if len(faces) == 0:
        return 0.0
    tri = vertices[faces]
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
    return float(edges.max()) if math.isfinite(float(edges.max())) else 0.0
