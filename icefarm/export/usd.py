"""A rendered job as an OpenUSD scene: ``scene.usda`` beside the renders, for any DCC.

``scene.usda`` is a small text layer with what an artist edits (cameras, lights, materials)
and references the heavy meshes, binary ``object.usdc`` and ``ice.usdc``, by relative paths:
the job folder moves as a whole. Everything is in meters (``metersPerUnit`` 1) in the job's
own frame, the points exactly those of ``object.ply`` and ``ice.ply``; the cameras, sun and
sky are the ones Mitsuba rendered (the job's `SceneSpec`, `icefarm.scene.read_scene_spec`).

Written with Pixar's ``usd-core`` (``pxr``), never by hand. Most of the time goes to the
normals and to the crate writer compressing the face indices (to a quarter of their size);
a job's ``timings.json`` reports its ``usd`` step.
"""

from __future__ import annotations

import dataclasses
import os
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade, UsdUtils, Vt

from ..artifacts import read_ice_mesh
from ..errors import InputError
from ..jobdir import ICE, ICE_BANDS, ICE_USDC, OBJECT, OBJECT_USDC, PARAMS, SCENE_USDA, SCENE_XML
from ..scene import IceLook, Material, SceneSpec, read_scene_spec
from .looks import TINT_DISTANCE_M, ice_color, pbr, perceptual_roughness, sun_light
from .meshes import Flow, Surface, ice_surface, object_surface, read_flow, require, water_at

SCENE_FILE, OBJECT_FILE, ICE_FILE = SCENE_USDA, OBJECT_USDC, ICE_USDC  # (`icefarm.jobdir`)
# Film back of the cameras: 36 mm wide (full frame), in USD's tenths of a scene unit. Only
# its ratio to the focal length (the field of view) matters for the picture.
FILM_WIDTH = 0.36
# The sun's apparent diameter, degrees: Mitsuba's sun is a point, most DCCs soften shadows.
SUN_ANGLE = 0.53
# UsdPreviewSurface has no transmission: ice is a low opacity, which in "transparent"
# mode fades only the diffuse part and keeps the reflections. Not 0: importers that read
# opacity as plain alpha (some DCCs) would lose the ice altogether.
ICE_OPACITY = 0.1
ICE_PRIMVAR = "crest"  # the ice's milky ripple bands (ice.ply's `ICE_BANDS`), per vertex


@dataclass(frozen=True)
class UsdScene:
    """What `write_job_usd` wrote.

    Attributes
    ----------
    scene : Path
        ``scene.usda``.
    layers : tuple of Path
        The binary mesh layers it references (``object.usdc``, ``ice.usdc`` with ice).
    up_axis : str
        ``Y`` or ``Z`` (see `up_axis`).
    seconds : float
        Wall time of the writing.
    """

    scene: Path
    layers: tuple[Path, ...]
    up_axis: str
    seconds: float


def up_axis(gravity) -> str:
    """USD's up axis for a job with ``gravity`` ``(3,)``: ``"Y"`` or ``"Z"``.

    Gravity along -Y gives Y, along -Z gives Z. USD knows no other up axis, so any other
    gravity gets the nearer of the two (the larger of ``|g_y|`` and ``|g_z|``, Y on a tie):
    the points are never rotated, so such a scene opens tilted, as it was modelled.
    """
    g = np.abs(np.asarray(gravity, dtype=np.float64).reshape(3))
    return "Z" if g[2] > g[1] else "Y"


@dataclass(frozen=True)
class UsdInputs:
    """What a job's USD export reads from its folder (`read_usd_inputs`), for `write_usd`.

    Attributes
    ----------
    job_dir : Path
    spec : SceneSpec
        The scene as rendered: cameras, lights, materials, gravity.
    object_surface : Surface
        ``object.ply`` split along its creases, with normals.
    flow : Flow or None
        ``water.ply``: stage 1's water, shading the object by wetness; None without one.
    ice : trimesh.Trimesh or None
        ``ice.ply``; None for a scene without ice.
    """

    job_dir: Path
    spec: SceneSpec
    object_surface: Surface
    flow: Flow | None
    ice: trimesh.Trimesh | None


def read_usd_inputs(job_dir: str | Path, *, material: Material | None = None,
                    ice_mesh: trimesh.Trimesh | None = None) -> UsdInputs:
    """Read what `write_usd` needs from a job that rendered.

    Kept apart from the writing so that a job can read in its own thread and write in another
    while Mitsuba renders: on Python 3.11, `ast.parse` in two threads at once can fail with
    ``SystemError: AST constructor recursion depth mismatch`` (CPython gh-106905), and both
    sides parse: trimesh's PLY reader (through NumPy's dtype strings) and Mitsuba's integrators
    (``dr.syntax``). `pxr` writing parses nothing.

    Parameters
    ----------
    job_dir : path
        The job folder: ``scene.xml``, ``views.json``, ``params.yaml``, ``object.ply``,
        ``ice.ply``, ``water.ply`` and the sky image.
    material : Material, optional
        The object's material; default ``done.json``'s.
    ice_mesh : trimesh.Trimesh, optional
        The ice already in memory (the pipeline's): saves reading ``ice.ply`` again.

    Raises
    ------
    InputError
        Not a job that rendered (a file missing).
    """
    job_dir = Path(job_dir)
    require(job_dir, ICE, OBJECT, SCENE_XML, PARAMS)
    spec = read_scene_spec(job_dir, material)
    ice = None if spec.ice is None else read_ice_mesh(job_dir / ICE) if ice_mesh is None else ice_mesh
    return UsdInputs(job_dir, spec, object_surface(job_dir), read_flow(job_dir), ice)


def write_usd(inputs: UsdInputs, out_dir: str | Path | None = None, ice_normals: np.ndarray | None = None) -> UsdScene:
    """Write ``scene.usda``, ``object.usdc`` and ``ice.usdc`` from a job's `UsdInputs`.

    Parameters
    ----------
    inputs : UsdInputs
    out_dir : path, optional
        Where to write; default the job's folder. Elsewhere, the sky is named by its absolute path.
    ice_normals : (n, 3) float, optional
        The ice's vertex normals as the scene's writer computed them
        (`icefarm.scene.SceneFiles.ice_normals`), if at hand: `ice_surface` computes them otherwise.
    """
    start = time.perf_counter()
    job_dir, spec = inputs.job_dir, inputs.spec
    out_dir = job_dir if out_dir is None else Path(out_dir)
    axis = up_axis(spec.gravity)
    layers = [out_dir / OBJECT_FILE]
    obj = inputs.object_surface
    _write_mesh_layer(layers[0], "Object", obj, axis, _object_primvars(inputs.flow, obj), double_sided=True)
    if inputs.ice is not None:
        layers.append(write_ice_mesh(out_dir / ICE_FILE, inputs.ice, flip=spec.ice_flip, axis=axis,
                                     normals=ice_normals))
    else:  # no ice: no layer of an earlier run's ice beside the scene
        (out_dir / ICE_FILE).unlink(missing_ok=True)
    sky_file = job_dir / spec.sky.file
    sky = f"./{sky_file.name}" if out_dir.resolve() == job_dir.resolve() else str(sky_file.resolve())
    with authored(out_dir / SCENE_FILE) as stage:
        _scene(stage, spec, axis, sky, has_ice=len(layers) > 1)
    return UsdScene(out_dir / SCENE_FILE, tuple(layers), axis, time.perf_counter() - start)


def write_job_usd(job_dir: str | Path, *, material: Material | None = None,
                  ice_mesh: trimesh.Trimesh | None = None, out_dir: str | Path | None = None,
                  ice_normals: np.ndarray | None = None) -> UsdScene:
    """Write ``scene.usda``, ``object.usdc`` and ``ice.usdc`` for a job that rendered:
    `read_usd_inputs` (``material``, ``ice_mesh``), then `write_usd` (``out_dir``,
    ``ice_normals``); its ``seconds`` count both.

    Raises
    ------
    InputError
        Not a job that rendered (a file missing).
    """
    start = time.perf_counter()
    written = write_usd(read_usd_inputs(job_dir, material=material, ice_mesh=ice_mesh), out_dir, ice_normals)
    return dataclasses.replace(written, seconds=time.perf_counter() - start)


def write_ice_mesh(path: str | Path, mesh: trimesh.Trimesh, *, flip: bool, axis: str,
                   normals: np.ndarray | None = None) -> Path:
    """``ice.usdc``: the ice ``mesh`` (meters, the job's frame, as ``ice.ply``) as the default
    prim ``/Ice`` of a binary layer, wound outwards (``flip``: `SceneSpec.ice_flip`), with its
    ``crest`` primvar; ``axis`` the stage's up axis (`up_axis`), ``normals`` as `ice_surface`
    takes them. `write_job_usd` and `icefarm.export.ice_layer` reference it. Returns ``path``."""
    path = Path(path)
    surface = ice_surface(mesh.vertices, mesh.faces, flip, normals)
    surface = dataclasses.replace(surface, faces=surface.faces[crate_order(len(surface.faces))])
    _write_mesh_layer(path, "Ice", surface, axis, _ice_primvars(mesh))
    return path


def crate_order(count: int) -> np.ndarray:
    """The order ``ice.usdc`` lists the ice's ``count`` faces in: a fixed shuffle.

    The crate writer compresses ``faceVertexIndices`` by their differences, and on marching
    cubes' order, where neighbouring faces share nearby vertices, its count of those
    differences slows down badly, holding the GIL all the while (the render waits for it):
    saving the 2.5 m shelter's 2.3 M lookdev faces took 10.7 s in that order and 0.66 s
    shuffled, the 1.5 m car's 1.58 s and 0.65 s. Runs of 4 to 256 faces kept in order were as
    slow as none shuffled (4.9-12 s), and renumbering the points by first use took 7.6 s.
    Shuffled indices compress less: the shelter's ``ice.usdc`` grows from 38 to 49 MB. The
    same permutation for the same count, so the same ice gives the same file.
    """
    return np.random.default_rng(0).permutation(count)


def write_usdz(job_dir: str | Path, out: str | Path) -> Path:
    """One ``.usdz`` file (scene, meshes and sky) of a job that rendered, at ``out``.

    Packs the job's ``scene.usda`` with `UsdUtils.CreateNewUsdzPackage`; a job written
    before icefarm wrote USD gets one first, in a temporary folder (the job is left as is).

    Raises
    ------
    InputError
        Not a job that rendered, or the packaging failed.
    """
    import tempfile

    job_dir, out = Path(job_dir), Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".usdz.") as tmp:
        scene = job_dir / SCENE_FILE
        if not scene.is_file():
            scene = write_job_usd(job_dir, out_dir=tmp).scene
        packed = Path(tmp) / out.name
        # The packager resolves references and the sky and stores them uncompressed, aligned.
        if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(scene)), str(packed)) or not packed.is_file():
            raise InputError(f"{job_dir}: packing {scene.name} into a usdz failed")
        os.replace(packed, out)
    return out


@contextmanager
def authored(path: Path) -> Iterator[Usd.Stage]:
    """A new stage saved to ``path`` whole or not at all.

    The stage is made at a hidden unique name in the same folder (so relative references
    resolve, and a layer of the same name open in this process is not reused), saved, then
    renamed over ``path``.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:12]}{path.suffix}")
    try:
        stage = Usd.Stage.CreateNew(str(tmp))
        yield stage
        stage.GetRootLayer().Save()
        del stage
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _stage_metadata(stage: Usd.Stage, axis: str, default: Usd.Prim) -> None:
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if axis == "Z" else UsdGeom.Tokens.y)
    stage.SetDefaultPrim(default)


def _write_mesh_layer(path: Path, name: str, surface: Surface, axis: str, primvars: dict,
                      double_sided: bool = False) -> None:
    """One mesh as the default prim of a binary layer (it opens on its own too).

    ``primvars``: name to ``(values, type name)``, one value per vertex. ``double_sided``:
    shade both sides (an asset with open seams shows its inside through them).
    """
    with authored(path) as stage:
        mesh = UsdGeom.Mesh.Define(stage, f"/{name}")
        _stage_metadata(stage, axis, mesh.GetPrim())
        points = np.ascontiguousarray(surface.vertices, dtype=np.float32)
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(surface.faces), 3, dtype=np.int32)))
        indices = np.ascontiguousarray(surface.faces, dtype=np.int32).ravel()
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices))
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(surface.normals, dtype=np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        # Triangles as they are: the default, Catmull-Clark, would smooth them and ignore the normals.
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        if double_sided:
            mesh.CreateDoubleSidedAttr(True)
        lo, hi = (points.min(axis=0), points.max(axis=0)) if len(points) else (np.zeros(3), np.zeros(3))
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        api = UsdGeom.PrimvarsAPI(mesh)
        for key, (values, type_name) in primvars.items():
            array = Vt.FloatArray.FromNumpy(values) if type_name == Sdf.ValueTypeNames.FloatArray \
                else Vt.IntArray.FromNumpy(values)
            api.CreatePrimvar(key, type_name, UsdGeom.Tokens.vertex).Set(array)


def _object_primvars(flow: Flow | None, obj: Surface) -> dict:
    """Stage 1's ``water`` (float) and ``supply`` (int, 0 or 1) per object vertex, to shade
    by wetness; nothing for a job without ``water.ply``."""
    if flow is None:
        return {}
    water, supply = water_at(flow, obj.vertices)
    return {"water": (water.astype(np.float32), Sdf.ValueTypeNames.FloatArray),
            "supply": (supply.astype(np.int32), Sdf.ValueTypeNames.IntArray)}


def _ice_primvars(mesh: trimesh.Trimesh) -> dict:
    """``crest`` (float, 0 to 1) per ice vertex: how far under a ripple crest, where impure ice
    is milky (the render's shimmer), for a DCC shader to frost by; nothing for clear ice."""
    bands = mesh.vertex_attributes.get(ICE_BANDS)
    if bands is None or len(bands) != len(mesh.vertices):
        return {}
    return {ICE_PRIMVAR: (np.asarray(bands, dtype=np.float32), Sdf.ValueTypeNames.FloatArray)}


def _scene(stage: Usd.Stage, spec: SceneSpec, axis: str, sky: str, has_ice: bool) -> None:
    """The contents of ``scene.usda``: /World with Object, Ice, Looks, Cameras and Lights."""
    world = UsdGeom.Xform.Define(stage, "/World")
    _stage_metadata(stage, axis, world.GetPrim())
    stage.GetRootLayer().documentation = "icefarm job: object and ice as rendered (meters)"
    looks = UsdGeom.Scope.Define(stage, "/World/Looks").GetPath()
    meshes = [("Object", OBJECT_FILE, _object_material(stage, looks, spec.material))]
    if has_ice:
        meshes.append(("Ice", ICE_FILE, ice_material(stage, looks, spec.ice)))
    for name, layer, material in meshes:
        prim = stage.DefinePrim(f"/World/{name}")  # a Mesh, by its reference
        prim.GetReferences().AddReference(f"./{layer}")
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    if spec.ground is not None:
        _ground(stage, looks, spec.ground)
    UsdGeom.Scope.Define(stage, "/World/Cameras")
    width, height = spec.resolution
    for camera, view in zip(spec.cameras, spec.views):
        _camera(stage, f"/World/Cameras/{Tf.MakeValidIdentifier(view.name)}", camera, width / height)
    UsdGeom.Scope.Define(stage, "/World/Lights")
    sun = sun_light(spec)
    if sun is not None:
        _sun(stage, *sun)
    # DomeLight (not DomeLight_1): its pole is +Y whatever the stage's up axis, and its
    # latlong layout (OpenEXR's: u = 0 at -Z, 1/4 at +X, the top row at +Y) is Mitsuba's
    # envmap's, so the sky's own to_world turns it the same way.
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath(sky))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(float(spec.sky.scale))
    dome.AddTransformOp().Set(_rows(spec.frame, np.zeros(3)))


def _ground(stage: Usd.Stage, looks: Sdf.Path, ground) -> None:
    """The ground the render stood the object on: a matte square of two triangles (its
    checker's mean colour)."""
    mesh = UsdGeom.Mesh.Define(stage, "/World/Ground")
    corners = np.asarray(ground.corners, dtype=np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(corners))
    mesh.CreateFaceVertexCountsAttr([3, 3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 0, 2, 3])
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(True)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, corners.min(axis=0))),
                                         Gf.Vec3f(*map(float, corners.max(axis=0)))]))
    material = _preview_surface(stage, looks.AppendChild("GroundMaterial"), {
        "diffuseColor": (Gf.Vec3f(*map(float, ground.color)), Sdf.ValueTypeNames.Color3f),
        "roughness": (1.0, Sdf.ValueTypeNames.Float),
        "useSpecularWorkflow": (1, Sdf.ValueTypeNames.Int),
        "specularColor": (Gf.Vec3f(0.0, 0.0, 0.0), Sdf.ValueTypeNames.Color3f)})
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def _rows(axes: np.ndarray, origin: np.ndarray) -> Gf.Matrix4d:
    """USD's matrix (row vectors) taking local X, Y, Z to the rows of ``axes`` ``(3, 3)``, then
    moving by ``origin`` ``(3,)``."""
    m = np.eye(4)
    m[:3, :3], m[3, :3] = axes, origin
    return Gf.Matrix4d(m.tolist())


def _camera(stage: Usd.Stage, path: str, camera, aspect: float) -> None:
    """A USD camera (looking down its local -Z, +Y up) where Mitsuba's ``lookat`` put it."""
    forward = camera.forward
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    cam = UsdGeom.Camera.Define(stage, path)
    cam.AddTransformOp().Set(_rows(np.stack([right, np.cross(right, forward), -forward]), camera.origin))
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateHorizontalApertureAttr(FILM_WIDTH)
    cam.CreateVerticalApertureAttr(FILM_WIDTH / aspect)
    cam.CreateFocalLengthAttr(float(FILM_WIDTH / 2 / np.tan(np.radians(camera.fov_x) / 2)))
    cam.CreateClippingRangeAttr(Gf.Vec2f(float(camera.near), float(camera.far)))


def _sun(stage: Usd.Stage, z: np.ndarray, intensity: float, color: np.ndarray) -> None:
    """The sun (`looks.sun_light`): a distant light shining along its local -Z, so local +Z
    (``z``) points at the sun; its intensity is Mitsuba's irradiance (W/m^2), its colour the
    irradiance's hue."""
    x = np.cross((0.0, 1.0, 0.0) if abs(z[1]) < 0.9 else (1.0, 0.0, 0.0), z)
    x /= np.linalg.norm(x)
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.AddTransformOp().Set(_rows(np.stack([x, np.cross(z, x), z]), np.zeros(3)))
    sun.CreateIntensityAttr(intensity)
    sun.CreateColorAttr(Gf.Vec3f(*color.tolist()))
    sun.CreateAngleAttr(SUN_ANGLE)


def _preview_surface(stage: Usd.Stage, path: Sdf.Path, inputs: dict) -> UsdShade.Material:
    """A Material with one UsdPreviewSurface shader; ``inputs``: name to ``(value, type)``."""
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path.AppendChild("PreviewSurface"))
    shader.CreateIdAttr("UsdPreviewSurface")
    for name, (value, type_name) in inputs.items():
        shader.CreateInput(name, type_name).Set(value)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _object_material(stage: Usd.Stage, looks: Sdf.Path, material: Material) -> UsdShade.Material:
    """The manifest material: diffuse (no highlight: specular workflow, black specular),
    plastic, or metal (its F0 as base colour)."""
    look = pbr(material)
    color = Gf.Vec3f(*map(float, look.base_color))
    inputs = {"diffuseColor": (color, Sdf.ValueTypeNames.Color3f),
              "roughness": (look.roughness, Sdf.ValueTypeNames.Float),
              "metallic": (look.metallic, Sdf.ValueTypeNames.Float)}
    if not look.specular:
        inputs.update(useSpecularWorkflow=(1, Sdf.ValueTypeNames.Int),
                      specularColor=(Gf.Vec3f(0.0, 0.0, 0.0), Sdf.ValueTypeNames.Color3f))
    return _preview_surface(stage, looks.AppendChild("ObjectMaterial"), inputs)


def ice_material(stage: Usd.Stage, looks: Sdf.Path, ice: IceLook) -> UsdShade.Material:
    """``looks/IceMaterial``: a MaterialX OpenPBR network (`_ice_openpbr`: glass that
    transmits, refracts and absorbs, for readers of MaterialX), and beside it the
    UsdPreviewSurface fallback: ior 1.31, low opacity, its roughness, and as diffuse colour
    the tint of thick ice (`looks.ice_color`), since UsdPreviewSurface has no transmission."""
    material = _preview_surface(stage, looks.AppendChild("IceMaterial"), {
        "diffuseColor": (Gf.Vec3f(*map(float, ice_color(ice))), Sdf.ValueTypeNames.Color3f),
        "roughness": (perceptual_roughness(ice.roughness), Sdf.ValueTypeNames.Float),
        "metallic": (0.0, Sdf.ValueTypeNames.Float),
        "ior": (ice.ior, Sdf.ValueTypeNames.Float),
        "opacity": (ICE_OPACITY, Sdf.ValueTypeNames.Float),
        # UsdPreviewSurface 2.5 (USD 23.11): "transparent" keeps the reflections at low
        # opacity. Older readers ignore an input they do not know.
        "opacityMode": ("transparent", Sdf.ValueTypeNames.Token),
    })
    _ice_openpbr(stage, material, ice)
    return material


# MaterialX's OpenPBR Surface node (MaterialX 1.39), bound as the material's ``mtlx``
# surface: usdview (Storm), Houdini (Karma), Maya (USD for Maya) and Omniverse read it;
# Blender's importer needs `icefarm/dcc/blender_usd_hook.py`.
OPENPBR_ID = "ND_open_pbr_surface_surfaceshader"


def _ice_openpbr(stage: Usd.Stage, material: UsdShade.Material, ice: IceLook) -> UsdShade.Shader:
    """The ice as OpenPBR Surface: no diffuse base, full transmission at its ior, the colour
    white light has after `TINT_DISTANCE_M` of it (``transmission_color`` at that
    ``transmission_depth``), and its scattering as ``transmission_scatter`` (the scattering
    coefficient times that depth)."""
    shader = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("OpenPBR"))
    shader.CreateIdAttr(OPENPBR_ID)
    color = lambda v: Gf.Vec3f(*(float(np.clip(c, 0.0, 1.0)) for c in v))  # noqa: E731
    scatter = min(float(ice.scattering) * TINT_DISTANCE_M, 1.0)
    for name, value, type_name in (
            ("base_weight", 0.0, Sdf.ValueTypeNames.Float),
            ("specular_weight", 1.0, Sdf.ValueTypeNames.Float),
            ("specular_ior", float(ice.ior), Sdf.ValueTypeNames.Float),
            ("specular_roughness", perceptual_roughness(ice.roughness), Sdf.ValueTypeNames.Float),
            ("transmission_weight", 1.0, Sdf.ValueTypeNames.Float),
            ("transmission_color", color(ice_color(ice)), Sdf.ValueTypeNames.Color3f),
            ("transmission_depth", float(TINT_DISTANCE_M), Sdf.ValueTypeNames.Float),
            ("transmission_scatter", color((scatter,) * 3), Sdf.ValueTypeNames.Color3f),
            ("geometry_thin_walled", False, Sdf.ValueTypeNames.Bool)):
        shader.CreateInput(name, type_name).Set(value)
    material.CreateSurfaceOutput("mtlx").ConnectToSource(shader.ConnectableAPI(), "surface")
    return shader
