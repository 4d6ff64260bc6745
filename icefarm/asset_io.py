"""Read a mesh file with what it says of its own size and orientation.

USD stages (usd-core) and glTF scenes carry units and an up axis: their meshes are read
with every prim's or node's world transform applied, and come with their meters per unit
and up axis, so they need no ``size_m`` and set gravity. OBJ, PLY, STL and OFF carry
neither: they need a ``size_m``, and keep the default gravity (-Y). Text files in latin-1
or cp1252 (a comment with an accented letter), or starting with a byte-order mark (as some
Windows tools save them), read as well as plain UTF-8 ones: `_as_utf8` is the one place that
makes a mesh file's text readable, for every format.
"""

from __future__ import annotations

import codecs
import io
import json
import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .errors import InputError
from .generators import GENERATOR_PREFIX
from .geometry import ragged_arange

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
GLTF_SUFFIXES = (".glb", ".gltf")
# Gravity for each up axis a file may declare: USD knows Y and Z; glTF is always +Y up.
UP_GRAVITY = {"Y": (0.0, -1.0, 0.0), "Z": (0.0, 0.0, -1.0)}
GRAVITY_KEY = "water.gravity"
# glTF extensions a file may require that change only its look (materials, textures, lights),
# not its triangles: icefarm reads the geometry without them.
GLTF_LOOK_PREFIXES = ("KHR_materials_", "KHR_texture_", "EXT_texture_", "KHR_lights_")
DRACO = "KHR_draco_mesh_compression"  # decoded by trimesh's handler with DracoPy
# Integer positions: trimesh reads them as they are, which is right unless they are normalized
# (to [-1, 1], to be scaled back by the reader, which trimesh does not do).
QUANTIZED = "KHR_mesh_quantization"
# Byte-order marks and the text they start: trimesh and usd-core read the mark as text (an
# OBJ's first vertex is lost and every face index shifts; a .usda or .gltf is refused).
BOMS = ((codecs.BOM_UTF8, "utf-8"), (codecs.BOM_UTF16_LE, "utf-16-le"), (codecs.BOM_UTF16_BE, "utf-16-be"))


@dataclass(frozen=True)
class Asset:
    """The triangles of a mesh file, in its own units, in world space.

    Attributes
    ----------
    vertices : (n, 3) float
        In the file's units, every transform above each mesh applied.
    faces : (m, 3) int
        Triangles (polygons fanned), indices into ``vertices``.
    meters_per_unit : float or None
        Meters per file unit; None when the format carries no units (OBJ, PLY, STL, OFF).
    up_axis : str or None
        ``"Y"`` or ``"Z"``; None when the format says nothing (gravity stays as set).
    """

    vertices: np.ndarray
    faces: np.ndarray
    meters_per_unit: float | None = None
    up_axis: str | None = None

    @property
    def gravity(self) -> tuple[float, float, float] | None:
        """Unit gravity its up axis implies, or None."""
        return UP_GRAVITY[self.up_axis] if self.up_axis else None


def carries_units(path: str | Path) -> bool:
    """Whether the format of ``path`` gives its size in meters (USD, glTF/GLB), by suffix."""
    return Path(path).suffix.lower() in USD_SUFFIXES + GLTF_SUFFIXES


# Sizes (m) past which `size_hint` asks whether the unit was meant: a 5 cm trinket, a 100 m
# tower; outside them the physical storm's 2.5 cm icicle spacing is either nothing or kilometres.
UNLIKELY_SIZE_M = (0.05, 100.0)


def missing_size(mesh: str) -> str | None:
    """Why ``mesh`` (a path or ``generator:NAME``) needs a ``size_m``, or None when it carries
    its own size (USD, glTF/GLB, the generators' real-size assets)."""
    if mesh.startswith(GENERATOR_PREFIX):
        from .generators import natural_size

        return None if natural_size(mesh[len(GENERATOR_PREFIX):]) is not None else f"{mesh} is in arbitrary units"
    if carries_units(mesh):
        return None
    return f"{mesh}: the {Path(mesh).suffix.lstrip('.').upper() or 'file'} format carries no units"


def size_hint(size_m: float) -> str | None:
    """A line asking about a ``size_m`` no asset is likely to have (a size in millimetres or
    centimetres given as meters), or None. The size still runs: a 10 km object is valid."""
    if size_m > UNLIKELY_SIZE_M[1]:
        return (f"size {size_m:g} m is taller than most buildings: if it is in centimetres or millimetres, "
                f"the size in meters is {size_m / 100:g} or {size_m / 1000:g}")
    if size_m < UNLIKELY_SIZE_M[0]:
        return (f"size {size_m:g} m is {size_m * 1000:g} mm, too small to hang an icicle "
                f"(drips.spacing is 2.5 cm): the size is a height in meters")
    return None


def read_asset(path: str | Path) -> Asset:
    """Read every visible mesh of ``path`` as one `Asset`.

    USD (``.usd``, ``.usda``, ``.usdc``, ``.usdz``): every ``Mesh`` prim that is visible and
    not a guide (proxies only when the stage has no render meshes), at its world transform
    (earliest time sample), with the stage's ``metersPerUnit`` (USD's fallback when
    unauthored: 0.01, centimetres) and ``upAxis``. glTF/GLB: every mesh node at its world
    transform; meters, +Y up (the glTF spec). Anything else trimesh reads: as it is, no units.

    Raises
    ------
    InputError
        The file is missing, unreadable, holds no triangles, or has non-finite vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"mesh file not found: {path}")
    suffix = path.suffix.lower()
    logging.getLogger("trimesh").setLevel(logging.ERROR)  # missing .mtl files are noise here
    try:
        if suffix in USD_SUFFIXES:
            asset = _read_usd(path)
        elif suffix in GLTF_SUFFIXES:
            asset = _read_gltf(path)
        else:
            asset = _read_unitless(path, suffix)
    except InputError:
        raise
    except Exception as exc:  # trimesh and usd-core raise many types for unreadable files
        raise InputError(f"cannot read mesh {path}: {exc}") from None
    if len(asset.faces) == 0 or len(asset.vertices) == 0:
        raise InputError(f"mesh {path} holds no triangles")
    if not np.isfinite(asset.vertices).all():
        raise InputError(f"mesh {path} has NaN or infinite vertex coordinates")
    if asset.meters_per_unit is not None and not (np.isfinite(asset.meters_per_unit) and asset.meters_per_unit > 0):
        raise InputError(f"mesh {path} declares {asset.meters_per_unit!r} meters per unit; "
                         "fix metersPerUnit in the file, or pass --size-m / size_m")
    return asset


def asset_gravity(mesh: str) -> tuple[float, float, float] | None:
    """Gravity the up axis of ``mesh`` (a path or ``generator:NAME``) implies, None when its
    format declares none. Reads only the stage's metadata for USD."""
    suffix = Path(mesh).suffix.lower()
    if mesh.startswith(GENERATOR_PREFIX) or suffix not in USD_SUFFIXES + GLTF_SUFFIXES:
        return None  # generators are Y-up, as the default gravity
    if suffix in GLTF_SUFFIXES:
        return UP_GRAVITY["Y"]
    from pxr import Usd, UsdGeom

    try:
        stage = _open_usd(Path(mesh), Usd.Stage.LoadNone)
    except Exception as exc:
        raise InputError(f"cannot read USD stage {mesh}: {exc}") from None
    return UP_GRAVITY[_usd_up_axis(stage, UsdGeom)]


def with_asset_gravity(mesh: str, values: dict) -> dict:
    """``values`` (flat ``{"group.name": value}``) with ``water.gravity`` from the up axis of
    ``mesh`` when they do not set it (and the file declares one)."""
    if GRAVITY_KEY in values:
        return values
    gravity = asset_gravity(mesh)
    return values if gravity is None else {**values, GRAVITY_KEY: list(gravity)}


def _usd_up_axis(stage, UsdGeom) -> str:
    return "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"


def _open_usd(path: Path, load=None):
    """``Usd.Stage.Open`` of ``path``; a .usda starting with a byte-order mark (which usd-core
    refuses) is read from its text, in a layer that keeps the file's path so that relative
    references still resolve beside it."""
    from pxr import Sdf, Usd

    load = Usd.Stage.LoadAll if load is None else load
    if path.suffix.lower() != ".usda" or not _bom(path):
        return Usd.Stage.Open(str(path), load=load)
    text = _as_utf8(path.read_bytes(), ".usda").decode("utf-8")
    layer = Sdf.Layer.New(Sdf.FileFormat.FindById("usda"), str(path.resolve())) \
        or Sdf.Layer.CreateAnonymous(".usda")  # New refuses a path already open in this process
    if not layer.ImportFromString(text):
        raise InputError(f"cannot read USD stage {path}")
    return Usd.Stage.Open(layer, load=load)


def _read_usd(path: Path) -> Asset:
    from pxr import Usd, UsdGeom

    stage = _open_usd(path)
    if stage is None:
        raise InputError(f"cannot read USD stage {path}")
    time = Usd.TimeCode.EarliestTime()  # a static value, or the first frame of an animation
    xforms = UsdGeom.XformCache(time)
    by_purpose: dict[str, list] = {"render": [], "proxy": []}
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        imageable = UsdGeom.Imageable(prim)
        if imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        purpose = imageable.ComputePurpose()
        if purpose == UsdGeom.Tokens.guide:
            continue
        part = _usd_mesh(UsdGeom.Mesh(prim), np.array(xforms.GetLocalToWorldTransform(prim)), time, path)
        by_purpose["proxy" if purpose == UsdGeom.Tokens.proxy else "render"].append(part)
    parts = by_purpose["render"] or by_purpose["proxy"]  # a proxy stands in for its render mesh
    if not parts:
        raise InputError(f"USD stage {path} holds no visible Mesh prim")
    vertices, faces = _concatenate(parts)
    return Asset(vertices, faces, float(UsdGeom.GetStageMetersPerUnit(stage)), _usd_up_axis(stage, UsdGeom))


def _usd_mesh(mesh, world: np.ndarray, time, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """One ``UsdGeom.Mesh``'s points in world space ``(n, 3)`` and its faces fanned ``(m, 3)``.

    ``world`` is USD's 4x4 row-vector matrix (``p' = [p, 1] @ world``).
    """
    points = np.asarray(mesh.GetPointsAttr().Get(time) or [], dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(time) or [], dtype=np.int64)
    name = f"{path}:{mesh.GetPath()}"
    if counts.sum() != len(indices) or (counts < 0).any():
        raise InputError(f"mesh {name}: faceVertexCounts add up to {counts.sum()}, "
                         f"but there are {len(indices)} faceVertexIndices; fix the mesh in its DCC")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
        raise InputError(f"mesh {name} has faces that name points it does not have")
    keep = np.ones(len(counts), dtype=bool)
    keep[holes[(holes >= 0) & (holes < len(counts))]] = False
    faces = fan_triangulate(counts, indices, keep)
    # A left-handed mesh, or a mirroring transform, winds its faces clockwise: turn them.
    mirrored = np.linalg.det(world[:3, :3]) < 0
    if (mesh.GetOrientationAttr().Get(time) == "leftHanded") != mirrored:
        faces = faces[:, ::-1]
    return points @ world[:3, :3] + world[3, :3], faces


def fan_triangulate(counts: np.ndarray, indices: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Polygons as triangle fans.

    Parameters
    ----------
    counts : (f,) int
        Corners of each polygon (USD's ``faceVertexCounts``); under 3: no triangle.
    indices : (sum(counts),) int
        Their vertex indices, polygon after polygon (``faceVertexIndices``).
    keep : (f,) bool, optional
        Polygons to triangulate (False: a hole).

    Returns
    -------
    (sum(max(counts - 2, 0)), 3) int
        Triangles ``(c0, ck, ck+1)``, wound as their polygons; exact for convex ones.
    """
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.cumsum(counts) - counts
    triangles = np.maximum(counts - 2, 0) * (True if keep is None else keep)
    polygon = np.repeat(np.arange(len(counts)), triangles)
    k = ragged_arange(triangles)  # 0..n-3
    first = starts[polygon]
    indices = np.asarray(indices, dtype=np.int64)
    return np.column_stack([indices[first], indices[first + k + 1], indices[first + k + 2]])


def _read_gltf(path: Path) -> Asset:
    required = _gltf_required(path)
    scene = _load_trimesh(path, path.suffix.lower())
    if isinstance(scene, trimesh.Trimesh):
        scene = trimesh.Scene(scene)
    parts = []
    for node in scene.graph.nodes_geometry:
        world, name = scene.graph[node]
        geometry = scene.geometry.get(name)
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):  # not points or lines
            if DRACO in required and not np.ptp(geometry.vertices, axis=0).any():
                # trimesh leaves zeros where its Draco handler failed, and only logs it
                raise InputError(f"glTF file {path}: a Draco-compressed mesh did not decode "
                                 "(a damaged file?); export it again, or without Draco compression")
            faces = np.asarray(geometry.faces, dtype=np.int64)
            parts.append((trimesh.transform_points(geometry.vertices, world),
                          faces[:, ::-1] if np.linalg.det(world[:3, :3]) < 0 else faces))
    if not parts:
        raise InputError(f"glTF file {path} holds no triangle mesh")
    vertices, faces = _concatenate(parts)
    return Asset(vertices, faces, 1.0, "Y")  # the glTF spec: meters, +Y up


def _gltf_required(path: Path) -> set[str]:
    """The extensions the glTF or GLB at ``path`` lists as required, once checked readable.

    Raises
    ------
    InputError
        A required extension that changes the geometry and that icefarm cannot decode (named),
        or Draco compression without the DracoPy package.
    """
    try:
        from trimesh.exchange.gltf.extensions import unregistered
    except ImportError:  # a trimesh before extension handlers decodes none
        def unregistered(names, scope):
            return set(names)

    header = _gltf_header(path)
    required = header.get("extensionsRequired") if isinstance(header, dict) else None
    required = {str(name) for name in required} if isinstance(required, list) else set()
    for name in sorted(required):
        if name.startswith(GLTF_LOOK_PREFIXES) or (name == QUANTIZED and not _normalized_positions(header)):
            continue
        if name in unregistered([name], "primitive_preprocess"):
            raise InputError(f"glTF file {path} requires the extension {name}, which icefarm cannot read: "
                             f"export it without {name}")
        if name == DRACO:
            try:
                import DracoPy  # noqa: F401
            except ImportError:
                raise InputError(f"glTF file {path} is Draco-compressed ({DRACO}): "
                                 "install DracoPy (pip install DracoPy) to read it") from None
    return required


def _normalized_positions(header: dict) -> bool:
    """Whether any mesh of the glTF JSON ``header`` has normalized integer positions."""
    try:
        accessors = header.get("accessors") or []
        for mesh in header.get("meshes") or []:
            for primitive in mesh.get("primitives") or []:
                index = (primitive.get("attributes") or {}).get("POSITION")
                if isinstance(index, int) and 0 <= index < len(accessors) and accessors[index].get("normalized"):
                    return True
    except (AttributeError, TypeError):  # not the shape glTF has: trimesh will say what is wrong
        return False
    return False


def _gltf_header(path: Path) -> object:
    """The JSON of a .gltf, or of a .glb's first chunk; None when there is none to read
    (trimesh then says what is wrong with the file)."""
    try:
        with open(path, "rb") as f:
            head = f.read(20)
            if head[:4] == b"glTF":
                length, kind = struct.unpack("<I4s", head[12:20])
                text = f.read(length) if kind == b"JSON" else b""
            else:
                text = _as_utf8(head + f.read(), ".gltf")
        return json.loads(text)
    except (OSError, ValueError, struct.error):
        return None


def _read_unitless(path: Path, suffix: str) -> Asset:
    loaded = _load_trimesh(path, suffix, force="mesh")
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(f"mesh {path} holds no triangles")
    return Asset(np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64))


def _load_trimesh(path: Path, suffix: str, **kwargs):
    """``trimesh.load`` of ``path``, its text first made readable (`_as_utf8`) when it starts
    with a byte-order mark or is not UTF-8; files beside it (an OBJ's .mtl, a glTF's buffers)
    are still found."""
    if not _bom(path):
        try:
            return trimesh.load(path, process=False, **kwargs)
        except (UnicodeDecodeError, ImportError):
            # Not UTF-8: trimesh asks charset_normalizer (not installed) to guess, or fails.
            # The geometry is ASCII in every such format; only comments and names are not.
            pass
    data = _as_utf8(path.read_bytes(), suffix)
    return trimesh.load(file_obj=io.BytesIO(data), file_type=suffix.lstrip("."), process=False,
                        resolver=trimesh.resolvers.FilePathResolver(path), **kwargs)


def _bom(path: Path) -> bool:
    """Whether the file at ``path`` starts with a byte-order mark."""
    with open(path, "rb") as f:
        head = f.read(4)
    return any(head.startswith(mark) for mark, _ in BOMS)


def _as_utf8(data: bytes, suffix: str) -> bytes:
    """A mesh file's bytes with its text made readable as plain UTF-8.

    A leading byte-order mark is dropped (UTF-16 text, which only text formats can be,
    re-encoded as UTF-8). PLY: bytes over 127 in the (ASCII) header become ``?``, byte for
    byte, so a binary body stays where it was. Other text formats (OBJ, OFF, ASCII STL, glTF,
    USDA): UTF-8 as it is, else decoded as latin-1, which maps every byte (cp1252's letters
    too, as their latin-1 code points), written as UTF-8.
    """
    for mark, codec in BOMS:
        if data.startswith(mark):
            data = data[len(mark):]
            if codec != "utf-8" and suffix != ".ply":
                data = data.decode(codec, errors="replace").encode("utf-8")
            break
    if suffix == ".ply":
        end = data.find(b"end_header")
        header = bytes(b if b < 128 else ord("?") for b in data[:max(end, 0)])
        return header + data[len(header):]
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")


def _concatenate(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Meshes ``[(vertices, faces), ...]`` as one ``(vertices, faces)``."""
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    vertices = np.concatenate([v for v, _ in parts]).astype(np.float64)
    faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)]).astype(np.int64)
    return vertices, faces.reshape(-1, 3)
