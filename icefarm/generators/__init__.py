"""Meshes icefarm builds itself, so its scenes, demos and tests need nothing from outside.

All are Y-up (gravity is (0, -1, 0)) with their lowest point on y = 0. Manifests name them
as ``mesh: generator:<name>``. Four objects are in arbitrary units (`icefarm.mesh.prepare`
scales each to the size its manifest states):

========  ==================================================================================
teapot    the Utah teapot tessellated from Newell's 32 bicubic Bezier patches; like most
          downloaded models it is not watertight: the project's own problem mesh
fountain  a lower basin, a column, an upper bowl whose rim overhangs, a finial: a surface of
          revolution, one closed manifold (after Kim et al.'s fountain, the paper's Fig. 16 b)
roof      a house with a gable roof whose slabs overhang the walls (eaves) and the gable
          ends: one closed manifold
branch    a bent, tapered branch with three side twigs: one closed manifold
========  ==================================================================================

The box-modelled assets are at their real size, in meters (`natural_size` gives their
height), low-poly (tens to a few hundred faces) and each one closed manifold:

========  ==================================================================================
table     a garden table, 0.74 m: a 0.9 x 0.9 m top 3 cm thick on four legs with aprons
bench     a park bench, 0.95 m: three seat slats, two backrest slats, two side frames
car       a small car, 1.5 m high, 3.8 m long: body box, tapered cabin (sloped windscreen
          and rear window), four 12-sided wheels
fence     a picket fence, 1.0 m high, 2.4 m long: three posts, two rails, 12 pointed pickets
lamp      a street lamp, 3.5 m: plinth, pole, arm, a lamp head with a pitched lid
shelter   a bus shelter, 2.5 m: four posts, a glass back panel, a sloping roof slab
          overhanging 30 cm all round
sign      a sign on a post, 2.2 m: a 0.6 x 0.6 m plate
========  ==================================================================================

``detail`` sets the resolution of the unitless objects: face counts grow about as
``detail ** 2``; the default (`DEFAULT_DETAIL`) gives a few thousand faces. The assets
ignore it. Everything is deterministic.

Each unitless object has its module, with the shape tools it is built with: `teapot`
(Bezier patches), `fountain` (a lathe), `roof` (prisms), `branch` (tubes along Bezier
curves); the assets share `assets` (boxes, tapered boxes, extruded polygons); `_common`
holds the detail levels and the helpers they share.
"""

from __future__ import annotations

import difflib
import operator

import trimesh

from ..errors import InputError
from . import assets, branch, fountain, roof, teapot
from ._common import DEFAULT_DETAIL, MAX_DETAIL

__all__ = ["DEFAULT_DETAIL", "MAX_DETAIL", "generate", "generator_names", "natural_size"]


GENERATOR_PREFIX = "generator:"  # a mesh argument naming a generator: generator:<name>


def generator_names() -> tuple[str, ...]:
    """Names `generate` accepts, in a stable order."""
    return tuple(_GENERATORS)


def generate(name: str, detail: int | None = None) -> trimesh.Trimesh:
    """Build the named mesh.

    Parameters
    ----------
    name : str
        One of `generator_names()`.
    detail : int, optional
        Resolution level in ``[1, MAX_DETAIL]``; face counts grow about as ``detail ** 2``.
        None means `DEFAULT_DETAIL` (a few thousand faces). The assets ignore it.

    Returns
    -------
    trimesh.Trimesh
        Y-up, lowest point on y = 0, outward-facing triangles; in meters for the assets
        (`natural_size`), arbitrary units for the others.

    Raises
    ------
    InputError
        Unknown name (the message lists the valid ones and the nearest match) or a bad detail.
    """
    return _builder(name)(_check_detail(detail))


def natural_size(name: str) -> float | None:
    """Real height of a generated mesh, or None for one in arbitrary units.

    Parameters
    ----------
    name : str
        One of `generator_names()`.

    Returns
    -------
    float or None
        For the real-size assets (``table``, ``bench``, ``car``, ``fence``, ``lamp``,
        ``shelter``, ``sign``): the height of `generate`'s mesh along y, in meters (the
        size to keep when a job states none). None for ``teapot``, ``fountain``, ``roof``
        and ``branch``, which need a size.

    Raises
    ------
    InputError
        Unknown name, as `generate`.
    """
    _builder(name)
    return assets.HEIGHTS.get(name)


def _builder(name: str):
    build = _GENERATORS.get(name) if isinstance(name, str) else None
    if build is None:
        names = generator_names()
        hint = difflib.get_close_matches(str(name), names, n=1, cutoff=0.4)
        tip = f"; did you mean {hint[0]!r}?" if hint else ""
        raise InputError(f"unknown mesh generator {name!r}: choose one of {', '.join(names)}{tip}")
    return build


def _check_detail(detail) -> int:
    if detail is None:
        return DEFAULT_DETAIL
    try:
        if isinstance(detail, bool):
            raise TypeError
        level = operator.index(detail)
    except TypeError:
        raise InputError(f"mesh detail must be a whole number from 1 to {MAX_DETAIL}, "
                         f"got {detail!r}") from None
    if not 1 <= level <= MAX_DETAIL:
        raise InputError(f"mesh detail must be from 1 to {MAX_DETAIL}, got {level}")
    return level


_GENERATORS = {"teapot": teapot.teapot, "fountain": fountain.fountain, "roof": roof.roof,
               "branch": branch.branch, **assets.BUILDERS}
