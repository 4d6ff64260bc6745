"""The YAML side of a manifest: a strict loader, size limits, and the checks and wording of
problems that every section of the manifest shares."""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from ..errors import InputError, short_repr
from ..yaml_io import NumberLoader

MAX_VALUE_ITEMS = 10_000  # a parameter value holding more items is refused (a YAML alias bomb)
FOLDER_SAFE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")  # a job or sweep folder name, ASCII only
FOLDER_SAFE_RULE = "ASCII letters, digits, _ . -, not starting with _ . -"


def folder_safe(name: Any) -> bool:
    """Whether ``name`` may name a job or sweep folder: the whole string must match
    `FOLDER_SAFE` (``$`` alone would let a final newline through into the folder name)."""
    return isinstance(name, str) and FOLDER_SAFE.fullmatch(name) is not None


def read_yaml(path: Path) -> Any:
    """The data of the manifest at ``path`` (absolute), read with `StrictLoader`.

    Raises
    ------
    InputError
        The file is missing, cannot be read, is not UTF-8 or is not valid YAML.
    """
    if not path.is_file():
        raise InputError(f"manifest not found: {path}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read the manifest {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(f"{path}: not UTF-8 text: byte 0x{raw[exc.start]:02x} on line {line} "
                         f"(save the manifest as UTF-8)") from None
    try:
        return yaml.load(text, Loader=StrictLoader)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from None


class StrictLoader(NumberLoader):
    """`NumberLoader` (``5e-2`` is a float) that refuses a key given twice in one mapping (the
    plain loader keeps the last silently). Keys brought in by a merge (``<<: *base``) may be
    overridden."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.setdefault(key, key_node.start_mark)
                except TypeError:  # an unhashable key: the base class says so
                    continue
                if first is not key_node.start_mark:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping", node.start_mark,
                        f"found the key {short_repr(key)} twice (first on line {first.line + 1}); "
                        "a key may be given once", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def too_big(value: Any, limit: int = MAX_VALUE_ITEMS) -> bool:
    """Whether ``value`` holds more than ``limit`` items in all, counted without expanding it:
    YAML aliases nest lists that a repr or a walk would take to billions of items."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > limit:
            return True
        if isinstance(item, Mapping):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple, set)):
            stack.extend(item)
    return False


def describe(value: Any) -> str:
    """What a problem says was found: ``nothing``, ``int 5``, ``list``."""
    if value is None:
        return "nothing"
    return (f"{type(value).__name__} {short_repr(value)}" if not isinstance(value, (Mapping, list))
            else type(value).__name__)


def key_path(where: str, key: Any) -> str:
    """``where.key``, the path of a value that a problem names."""
    return f"{where}.{key}" if where else str(key)


def unknown_keys(data: Mapping, allowed: tuple[str, ...], where: str, errors: list[str]) -> None:
    """A problem for each key of ``data`` not in ``allowed``, with the nearest valid one."""
    for key in data:
        if key in allowed:
            continue
        key = short_repr(key) if not isinstance(key, str) or len(key) > 60 else key
        hint = difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.5)
        tip = f"did you mean {hint[0]!r}?" if hint else f"expected one of {', '.join(allowed)}"
        errors.append(f"{key_path(where, key)}: unknown key; {tip}")
