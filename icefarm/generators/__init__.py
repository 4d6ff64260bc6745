"""Meshes icefarm builds itself, so its scenes, demos and tests need nothing from outside.

Four objects, all Y-up (gravity is (0, -1, 0)) with their lowest point on y = 0, in arbitrary
units (`icefarm.mesh.prepare` scales each to the size its manifest states). Manifests name
them as ``mesh: generator:<name>``.

========  ==================================================================================
teapot    the Utah teapot tessellated from Newell's 32 bicubic Bezier patches; like most
          downloaded models it is not watertight: the project's own problem mesh
fountain  a lower basin, a column, an upper bowl whose rim overhangs, a finial: a surface of
          revolution, one closed manifold (after Kim et al.'s fountain, the paper's Fig. 16 b)
roof      a house with a gable roof whose slabs overhang the walls (eaves) and the gable
          ends: one closed manifold
branch    a bent, tapered branch with three side twigs: one closed manifold
========  ==================================================================================

``detail`` sets the resolution: face counts grow about as ``detail ** 2``; the default
(`DEFAULT_DETAIL`) gives a few thousand faces. Everything is deterministic.

Each object has its module, with the shape tools it is built with: `teapot` (Bezier
patches), `fountain` (a lathe), `roof` (prisms), `branch` (tubes along Bezier curves);
`_common` holds the detail levels and the helpers they share.
"""

from __future__ import annotations

import difflib
import operator

import trimesh

from ..errors import InputError
from . import branch, fountain, roof, teapot
from ._common import DEFAULT_DETAIL, MAX_DETAIL

__all__ = ["DEFAULT_DETAIL", "MAX_DETAIL", "generate", "generator_names"]


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
        None means `DEFAULT_DETAIL` (a few thousand faces).

    Returns
    -------
    trimesh.Trimesh
        Y-up, lowest point on y = 0, arbitrary units, outward-facing triangles.

    Raises
    ------
    InputError
        Unknown name (the message lists the valid ones and the nearest match) or a bad detail.
    """
    build = _GENERATORS.get(name) if isinstance(name, str) else None
    if build is None:
        names = generator_names()
        hint = difflib.get_close_matches(str(name), names, n=1, cutoff=0.4)
        tip = f"; did you mean {hint[0]!r}?" if hint else ""
        raise InputError(f"unknown mesh generator {name!r}: choose one of {', '.join(names)}{tip}")
    return build(_check_detail(detail))


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
               "branch": branch.branch}
