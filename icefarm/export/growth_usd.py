"""``growth.usda``: the ice growing, as USD value clips, with the job's look around it.

Each growth frame's ice is its own small binary layer (``ice_0001.usdc``...: points,
topology, extent and normals at that frame's time code), written and closed one at a
time, so memory stays that of one frame; ``growth.usda`` stitches them with value clips
(`pxr.Usd.ClipsAPI`: one clip active per frame, a manifest naming what varies). Around the
ice it references what the job's ``scene.usda`` holds (the object, the materials with the
ice's MaterialX glass, the ground; cameras and lights), so the animation opens as the render
looked.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from ..jobdir import GROWTH_CLIPS, GROWTH_ICE_USDC, GROWTH_MANIFEST, growth_clip

CLIP_PRIM = "/Ice"
# Attributes each clip holds, with their USD type names (the manifest declares them).
CLIP_ATTRIBUTES = (("points", "point3f[]"), ("faceVertexCounts", "int[]"), ("faceVertexIndices", "int[]"),
                   ("extent", "float3[]"), ("normals", "normal3f[]"))


def write_growth_usd(path: Path, plies: Sequence[Path], gravity, fps: float, object_usd: str | Path | None = None,
                     scene_usd: str | Path | None = None) -> Path:
    """Write ``growth.usda`` at ``path``, its clips and manifest beside it.

    Parameters
    ----------
    path : Path
        ``growth/growth.usda``.
    plies : sequence of Path
        The frames' ice meshes, in order; frame i is time code i (1..N).
    gravity : (3,) float
        The up axis follows it (`icefarm.export.usd.up_axis`).
    fps : float
        ``timeCodesPerSecond``, the movie's.
    object_usd : path, optional
        The job's ``object.usdc``, referenced as ``/Growth/Object`` when it exists.
    scene_usd : path, optional
        The job's ``scene.usda``: its materials, ground, cameras and lights are referenced
        and the ice and ground bound to its materials, when it exists.

    Returns
    -------
    Path
        ``path``.
    """
    from pxr import Sdf, Usd, UsdGeom

    from .usd import up_axis

    folder = path.parent
    axis = UsdGeom.Tokens.z if up_axis(gravity) == "Z" else UsdGeom.Tokens.y
    for old in [path, folder / GROWTH_MANIFEST, *folder.glob(GROWTH_CLIPS), folder / GROWTH_ICE_USDC]:
        old.unlink(missing_ok=True)
    clips = [_write_clip(folder / growth_clip(i), ply, i, axis) for i, ply in enumerate(plies, 1)]
    _write_manifest(folder / GROWTH_MANIFEST)

    stage = Usd.Stage.CreateNew(str(path))
    root = UsdGeom.Xform.Define(stage, "/Growth")
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
    UsdGeom.SetStageUpAxis(stage, axis)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(max(len(plies), 1))
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetDefaultPrim(root.GetPrim())
    stage.GetRootLayer().documentation = "icefarm growth: the ice per frame as value clips (meters)"

    ice = UsdGeom.Mesh.Define(stage, "/Growth/Ice")
    ice.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # triangles as they are, not Catmull-Clark
    ice.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    api = Usd.ClipsAPI(ice.GetPrim())
    api.SetClipAssetPaths(Sdf.AssetPathArray([f"./{clip.name}" for clip in clips]))
    api.SetClipPrimPath(CLIP_PRIM)
    api.SetClipManifestAssetPath(Sdf.AssetPath(f"./{GROWTH_MANIFEST}"))
    api.SetClipActive([(float(i), float(i - 1)) for i in range(1, len(clips) + 1)])
    api.SetClipTimes([(float(i), float(i)) for i in range(1, len(clips) + 1)])

    if object_usd is not None and Path(object_usd).is_file():
        stage.DefinePrim("/Growth/Object").GetReferences().AddReference(_relative(object_usd, folder))
    if scene_usd is not None and Path(scene_usd).is_file():
        _the_jobs_look(stage, _relative(scene_usd, folder), ice)
    stage.GetRootLayer().Save()
    return path


def _write_clip(path: Path, ply: Path, time_code: int, axis: str) -> Path:
    """One frame's ice as ``/Ice`` with its values at ``time_code``, in its own layer."""
    from pxr import Gf, Usd, UsdGeom, Vt

    from ..scene.geometry import smooth_normals

    mesh = trimesh.load(ply, process=False, force="mesh")
    points = np.ascontiguousarray(mesh.vertices, dtype=np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32).reshape(-1, 3)
    normals = (smooth_normals(mesh.vertices, mesh.faces) if len(faces) else np.zeros((len(points), 3)))
    lo, hi = (points.min(axis=0), points.max(axis=0)) if len(points) else (np.zeros(3), np.zeros(3))
    stage = Usd.Stage.CreateNew(str(path))
    prim = UsdGeom.Mesh.Define(stage, CLIP_PRIM)
    UsdGeom.SetStageUpAxis(stage, axis)
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
    t = Usd.TimeCode(time_code)
    prim.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(points), t)
    prim.CreateFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)), t)
    prim.CreateFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(faces.ravel()), t)
    prim.CreateExtentAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]), t)
    prim.CreateNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals, dtype=np.float32)), t)
    stage.GetRootLayer().Save()
    return path


def _write_manifest(path: Path) -> None:
    """The clips' manifest: the attributes of ``/Ice`` whose values the clips give."""
    from pxr import Sdf

    layer = Sdf.Layer.CreateNew(str(path))
    prim = Sdf.PrimSpec(layer, CLIP_PRIM.strip("/"), Sdf.SpecifierOver)
    for name, type_name in CLIP_ATTRIBUTES:
        Sdf.AttributeSpec(prim, name, Sdf.ValueTypeNames.Find(type_name), Sdf.VariabilityVarying)
    layer.Save()


def _the_jobs_look(stage, scene: str, ice) -> None:
    """Reference ``scene.usda``'s looks, ground, cameras and lights under /Growth and bind
    the ice and the ground to its materials."""
    from pxr import UsdShade

    for name in ("Looks", "Ground", "Cameras", "Lights"):
        stage.DefinePrim(f"/Growth/{name}").GetReferences().AddReference(scene, f"/World/{name}")
    looks = stage.GetPrimAtPath("/Growth/Looks")
    for prim, material in ((ice.GetPrim(), "IceMaterial"), (stage.GetPrimAtPath("/Growth/Ground"), "GroundMaterial")):
        target = looks.GetChild(material)
        if prim and target:
            UsdShade.MaterialBindingAPI.Apply(prim).Bind(UsdShade.Material(target))


def _relative(target: str | Path, folder: Path) -> str:
    return Path(os.path.relpath(Path(target).resolve(), folder.resolve())).as_posix()
