"""Stage results to bytes and back without pickle: arrays in an ``.npz``, structure in JSON.

A stage result is a frozen dataclass of arrays, numbers, strings, enums, meshes and other
such dataclasses. `encode` writes its arrays into an uncompressed ``.npz`` (NumPy's format,
read back with ``allow_pickle=False``) and its structure as JSON beside them; `decode`
rebuilds it, creating only dataclasses and enums defined in icefarm's own modules. Loading
an entry therefore runs no code from the file, whoever wrote it (pickle would: whoever can
write a sweep's cache folder could run code in its workers).
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

MANIFEST = "__structure__"


class Unencodable(TypeError):
    """A value of a type the codec does not store (it is then computed, not cached)."""


def encode(value: Any) -> bytes:
    """``.npz`` bytes of ``value`` (see the module docstring).

    Raises
    ------
    Unencodable
        A part of ``value`` is not an array, number, string, bool, None, tuple, list,
        str-keyed dict, path, enum, trimesh mesh or icefarm dataclass of those.
    """
    arrays: dict[str, np.ndarray] = {}
    structure = _encode(value, arrays)
    arrays[MANIFEST] = np.frombuffer(json.dumps(structure).encode(), dtype=np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def decode(data: bytes) -> Any:
    """The value `encode` stored in ``data``.

    Raises
    ------
    ValueError
        Bytes that are not such an entry, or that name a type outside icefarm.
    """
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    structure = json.loads(arrays.pop(MANIFEST).tobytes().decode())
    return _decode(structure, arrays)


def _encode(value: Any, arrays: dict) -> Any:
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)) and not isinstance(value, enum.Enum):
        return {"f": float(value)} if isinstance(value, float) else value
    if isinstance(value, np.generic):
        return _encode(value.item(), arrays)
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise Unencodable("an array of Python objects")
        key = f"a{len(arrays)}"
        arrays[key] = value
        return {"array": key}
    if isinstance(value, enum.Enum):
        return {"enum": _name(type(value)), "value": _encode(value.value, arrays)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"dataclass": _name(type(value)),
                "fields": {f.name: _encode(getattr(value, f.name), arrays) for f in dataclasses.fields(value)}}
    if isinstance(value, (tuple, list)):
        return {"tuple" if isinstance(value, tuple) else "list": [_encode(v, arrays) for v in value]}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise Unencodable("a dict with keys that are not strings")
        return {"dict": {k: _encode(v, arrays) for k, v in value.items()}}
    if isinstance(value, Path):
        return {"path": str(value)}
    import trimesh

    if isinstance(value, trimesh.Trimesh):
        return {"trimesh": {"vertices": _encode(np.asarray(value.vertices), arrays),
                            "faces": _encode(np.asarray(value.faces), arrays)}}
    raise Unencodable(f"a {type(value).__module__}.{type(value).__qualname__}")


def _decode(node: Any, arrays: dict) -> Any:
    if node is None or isinstance(node, (bool, str, int)):
        return node
    if isinstance(node, dict):
        if "f" in node:
            return float(node["f"])
        if "array" in node:
            return arrays[node["array"]]
        if "tuple" in node:
            return tuple(_decode(v, arrays) for v in node["tuple"])
        if "list" in node:
            return [_decode(v, arrays) for v in node["list"]]
        if "dict" in node:
            return {k: _decode(v, arrays) for k, v in node["dict"].items()}
        if "path" in node:
            return Path(node["path"])
        if "enum" in node:
            cls = _icefarm_type(node["enum"])
            if not (isinstance(cls, type) and issubclass(cls, enum.Enum)):
                raise ValueError(f"{node['enum']} is not an enum")
            return cls(_decode(node["value"], arrays))
        if "dataclass" in node:
            cls = _icefarm_type(node["dataclass"])
            if not dataclasses.is_dataclass(cls):
                raise ValueError(f"{node['dataclass']} is not a dataclass")
            obj = object.__new__(cls)  # as stored: no __init__ or __post_init__ runs again
            names = {f.name for f in dataclasses.fields(cls)}
            for name, value in node["fields"].items():
                if name not in names:
                    raise ValueError(f"{node['dataclass']} has no field {name!r}")
                object.__setattr__(obj, name, _decode(value, arrays))
            return obj
        if "trimesh" in node:
            import trimesh

            mesh = node["trimesh"]
            return trimesh.Trimesh(_decode(mesh["vertices"], arrays), _decode(mesh["faces"], arrays), process=False)
    raise ValueError(f"not a stage cache structure: {str(node)[:80]}")


def _name(cls: type) -> str:
    if not cls.__module__.startswith("icefarm."):
        raise Unencodable(f"{cls.__module__}.{cls.__qualname__} is not icefarm's")
    return f"{cls.__module__}:{cls.__qualname__}"


def _icefarm_type(name: str) -> type:
    """The class ``module:qualname`` of an icefarm module (nothing else is imported)."""
    module, _, qualname = name.partition(":")
    if not module.startswith("icefarm.") or not qualname or "<" in qualname:
        raise ValueError(f"{name!r} is not an icefarm type")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    if not isinstance(obj, type):
        raise ValueError(f"{name!r} is not a class")
    return obj
