"""The ice as a USD layer over the asset it grew on: ``ice_layer.usda`` in the job folder.

USD pipelines work non-destructively: rather than a copy of the asset's meshes (what
``scene.usda`` holds, `icefarm.export.usd`), a small text layer of opinions that composes
over the asset's own file, so that later edits of the asset show through and nothing is
duplicated. The layer

- brings in the asset by a **reference** to its file (a relative path when one exists,
  ``./`` or ``../`` anchored at the layer) on a prim named as the asset's default prim, so
  the asset's prim paths are kept; an asset whose default prim is not its only root prim
  (or that has none) is **sublayered** instead, which keeps every root prim;
- adds under that root prim a group ``Icefarm`` (`GROUP`) holding the ice mesh ``Ice``
  and its material ``Looks/IceMaterial`` (`icefarm.export.usd.ice_material`: MaterialX
  OpenPBR glass beside a UsdPreviewSurface fallback, as ``scene.usda`` has it), so that
  the ice moves with the asset's root transform;
- carries the asset's ``metersPerUnit`` and ``upAxis``.

The ice's points are not in the layer: its ``Ice`` prim references the job's binary
``ice.usdc`` (the same file ``scene.usda`` references, written here for a job that did not
render), whose points are ``ice.ply``'s, in meters, in the job's frame. The group's one
transform takes them back to the asset: ``prepare`` made the job's frame as
``v * scale - offset`` from the asset's world space (in its units, its up axis kept: the
points are never turned, gravity follows the up axis instead), so the group holds
``(v + offset) / scale`` followed by the inverse of the root prim's world transform at the
time the job read it. Binary points beside a text layer keep the layer small (a large ice
mesh is hundreds of MB as text) and the float32 points near the origin, where they are
exact to a micrometre; the transform is double precision.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade

from ..artifacts import read_ice_mesh
from ..asset_io import USD_SUFFIXES
from ..errors import InputError
from ..jobdir import ICE, ICE_LAYER, ICE_USDC, SCENE_SPEC
from ..scene import IceLook, ice_at_impurity, read_scene_spec, winds_inward
from .usd import authored, ice_material, write_ice_mesh

GROUP = "Icefarm"  # the group under the asset's root prim: the ice and its material


@dataclass(frozen=True)
class IceLayer:
    """What `write_ice_layer` wrote.

    Attributes
    ----------
    layer : Path
        ``ice_layer.usda``.
    asset : str
        The asset's path as the layer names it (relative to the layer when one exists).
    arc : {"reference", "sublayer"}
        How the layer composes the asset.
    group : str
        Prim path of the ``Icefarm`` group (the ice's transform), under the asset's root prim.
    ice : str or None
        Prim path of the ice mesh; None when the job grew no ice.
    seconds : float
        Wall time of the writing.
    """

    layer: Path
    asset: str
    arc: str
    group: str
    ice: str | None
    seconds: float


def write_ice_layer(job_dir: str | Path, asset: str | Path, *, scale: float, offset: np.ndarray | Sequence[float],
                    impurity: float = 0.0, out: str | Path | None = None) -> IceLayer:
    """Write ``ice_layer.usda``: the job's ice composed over the USD ``asset`` it grew on.

    Parameters
    ----------
    job_dir : path
        The job folder: ``ice.ply``; ``scene.json`` when the job rendered (the ice's look is
        then the rendered one) and ``ice.usdc`` beside it (written here when missing or
        older than ``ice.ply``).
    asset : path
        The USD file the job read (``.usd``, ``.usda``, ``.usdc``, ``.usdz``).
    scale : float
        Meters per asset unit as the job prepared it (`icefarm.mesh.PreparedMesh.scale`).
    offset : (3,) float
        Meters subtracted after scaling (`icefarm.mesh.PreparedMesh.offset`).
    impurity : float
        ``surface.impurity``: how milky the ice of a job that did not render looks.
    out : path, optional
        Where to write; default ``job_dir/ice_layer.usda``.

    Returns
    -------
    IceLayer

    Raises
    ------
    InputError
        ``asset`` is not a USD file, or USD cannot open it (a ``.usda`` that starts with a
        byte-order mark: icefarm reads it, no USD tool does).
    """
    start = time.perf_counter()
    job_dir = Path(job_dir).absolute()
    out = job_dir / ICE_LAYER if out is None else Path(out).absolute()
    asset = Path(asset).absolute()
    if asset.suffix.lower() not in USD_SUFFIXES:
        raise InputError(f"{asset}: an ice layer composes over a USD asset ({', '.join(USD_SUFFIXES)})")
    try:
        source = Usd.Stage.Open(str(asset)) if asset.is_file() else None
    except Tf.ErrorException:  # e.g. a .usda starting with a byte-order mark: icefarm reads it, USD does not
        source = None
    if source is None:
        raise InputError(f"USD cannot open the asset {asset}, so no layer can compose over it: "
                         "save it again from a USD tool (a .usda without a byte-order mark)")
    mesh = read_ice_mesh(job_dir / ICE)
    ice, flip = _look(job_dir, mesh, impurity) if len(mesh.faces) else (None, False)
    axis = "Z" if UsdGeom.GetStageUpAxis(source) == UsdGeom.Tokens.z else "Y"
    usdc = job_dir / ICE_USDC
    if ice is not None and (not usdc.is_file() or usdc.stat().st_mtime_ns < (job_dir / ICE).stat().st_mtime_ns):
        write_ice_mesh(usdc, mesh, flip=flip, axis=axis)  # a job that did not render has none yet
    default = source.GetDefaultPrim()
    arc, root = _composition(source)
    # The job read the asset at its earliest time (`icefarm.asset_io.read_asset`)
    world = np.eye(4) if root is None else \
        np.array(UsdGeom.XformCache(Usd.TimeCode.EarliestTime()).GetLocalToWorldTransform(root))
    parent = Sdf.Path.absoluteRootPath if root is None else root.GetPath()
    group_path = _free_child(source, parent, GROUP)
    named = _anchored(asset, out.parent)
    with authored(out) as stage:
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(source))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(source))
        stage.GetRootLayer().documentation = f"icefarm: the ice of the job in {job_dir.name}, over {asset.name}"
        if arc == "reference":
            stage.DefinePrim(default.GetPath()).GetReferences().AddReference(named)
        else:
            stage.GetRootLayer().subLayerPaths.append(named)
        group = UsdGeom.Xform.Define(stage, group_path)  # an `over` for the asset's prims above it
        group.AddTransformOp().Set(Gf.Matrix4d((_to_asset(scale, offset) @ np.linalg.inv(world)).tolist()))
        ice_path = None
        if ice is not None:
            prim = stage.DefinePrim(group_path.AppendChild("Ice"))  # a Mesh, by its reference
            prim.GetReferences().AddReference(_anchored(usdc, out.parent))
            looks = UsdGeom.Scope.Define(stage, group_path.AppendChild("Looks")).GetPath()
            UsdShade.MaterialBindingAPI.Apply(prim).Bind(ice_material(stage, looks, ice))
            ice_path = str(prim.GetPath())
        if default:
            stage.SetDefaultPrim(stage.GetPrimAtPath(default.GetPath()))
    return IceLayer(out, named, arc, str(group_path), ice_path, time.perf_counter() - start)


def _composition(source: Usd.Stage) -> tuple[str, Usd.Prim | None]:
    """How the layer composes the asset ``source`` (``"reference"`` to its default prim when
    that is its only root prim, else ``"sublayer"``), and the prim the ice goes under: the
    default prim, else the only root prim; None (the stage's root) when there is neither, or
    when that prim is a gprim, which has no child prims."""
    default, roots = source.GetDefaultPrim(), source.GetPseudoRoot().GetChildren()
    arc = "reference" if default and [p.GetPath() for p in roots] == [default.GetPath()] else "sublayer"
    root = default if default else (roots[0] if len(roots) == 1 else None)
    return arc, None if root is not None and root.IsA(UsdGeom.Gprim) else root


def _to_asset(scale: float, offset: np.ndarray | Sequence[float]) -> np.ndarray:
    """``(4, 4)`` USD matrix (row vectors, ``p' = [p, 1] @ m``) taking the job's frame back to
    the asset's world space: ``(v + offset) / scale``, the inverse of `icefarm.mesh.prepare`."""
    m = np.eye(4) / float(scale)
    m[3] = [*(np.asarray(offset, dtype=np.float64).reshape(3) / float(scale)), 1.0]
    return m


def _look(job_dir: Path, mesh: trimesh.Trimesh, impurity: float) -> tuple[IceLook, bool]:
    """The ice's look and whether its faces wind inwards: as the job rendered them (its
    ``scene.json``), else the render configs' default ice at ``impurity``."""
    if (job_dir / SCENE_SPEC).is_file():
        spec = read_scene_spec(job_dir)
        if spec.ice is not None:
            return spec.ice, spec.ice_flip
    return ice_at_impurity(IceLook(), impurity), bool(winds_inward(mesh.vertices, mesh.faces))


def _free_child(stage: Usd.Stage, parent: Sdf.Path, name: str) -> Sdf.Path:
    """``parent/name``, or ``parent/name_1``, ... where the asset has a prim by that name."""
    path, n = parent.AppendChild(name), 0
    while stage.GetPrimAtPath(path):
        n += 1
        path = parent.AppendChild(f"{name}_{n}")
    return path


def _anchored(path: Path, folder: Path) -> str:
    """``path`` as a layer in ``folder`` names it: relative, anchored (``./``, ``../``), so it
    resolves beside the layer whatever the search paths; absolute where no relative path
    exists (another drive)."""
    try:
        rel = Path(os.path.relpath(path, folder)).as_posix()
    except ValueError:
        return path.as_posix()
    return rel if rel.startswith("../") else f"./{rel}"
