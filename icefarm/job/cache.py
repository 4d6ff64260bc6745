"""The stage cache: stage results (`icefarm.job.codec`: arrays and JSON, no pickle) under
keys hashed from their inputs.

A job's stage results are stored under a digest of everything the stage reads (inputs,
parameters, upstream keys) and of icefarm's source (`StageCache.code_version`), so a sweep
over surface parameters reuses stages 1-3 and a code change never reads stale results.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .. import artifacts, jobdir
from .codec import Unencodable, decode, encode

READ_ONLY = (errno.EACCES, errno.EPERM, errno.EROFS)  # a write refused: the cache is read, not written


def digest(*parts: Any) -> str:
    """sha256 (hex) of ``parts``: bytes as they are, anything else as sorted JSON (a
    parameter group as the mapping of its values, so keys do not depend on its type)."""
    h = hashlib.sha256()
    for part in parts:
        h.update(part if isinstance(part, bytes) else json.dumps(part, sort_keys=True, default=_plain).encode())
        h.update(b"\0")
    return h.hexdigest()


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    return str(value)


def file_digest(path: str | Path) -> str:
    """`icefarm.jobdir.file_digest` of an input file, computed once per (path, mtime,
    size): a sweep hashes each mesh once; ``missing:PATH`` when it cannot be read."""
    try:
        stat = Path(path).stat()
    except OSError:
        return f"missing:{path}"
    return _content_digest(str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=256)
def _content_digest(path: str, mtime_ns: int, size: int) -> str:
    try:
        return jobdir.file_digest(Path(path))
    except OSError:
        return f"missing:{path}"


class StageCache:
    """Stage results under ``root/<stage>/<key>.<code>.npz``; no root, no cache.

    ``<code>`` is `code_version` (a hash of icefarm's source): results of other code are
    never read. Each entry starts with a line ``icefarm-cache 2 <sha256 of the rest>``: an
    entry whose bytes no longer match (a bad disk, a copy cut short, a hand edit) is deleted
    and recomputed with a `CacheWarning`, never trusted. The rest is `stage_codec`'s: an
    ``.npz`` of arrays and JSON, loaded without pickle, rebuilding only icefarm's own
    dataclasses, so an entry written by someone else runs no code. A result the codec does
    not store is computed each time.

    ``root/policy.json`` (a sweep writes it, `write_policy`) may name ``private`` stages:
    their results are used by one job only, so they are not stored (they are still read when
    there).

    A cache that cannot be written (a studio's shared cache, read-only to the user) is read:
    what is there is reused, the rest computed and not stored (``read_only`` becomes True at
    the first write refused; whoever opened the cache says so once).
    """

    MAGIC = b"icefarm-cache 2"
    POLICY = "policy.json"
    _code: str | None = None

    def __init__(self, root: Path | None):
        self.root = root
        self.reused: list[str] = []
        self.warnings: list[str] = []
        self.private: set[str] = set()
        self.read_only = root is not None and root.is_dir() and not os.access(root, os.W_OK)
        if root is not None:
            try:
                self.private = {str(s) for s in json.loads((root / self.POLICY).read_text()).get("private", ())}
            except (OSError, ValueError, AttributeError, TypeError):
                pass

    @classmethod
    def code_version(cls) -> str:
        """Hash of icefarm's version and of every source file of the package (12 hex digits)."""
        if cls._code is None:
            from .. import __version__

            h = hashlib.sha256(__version__.encode())
            package = Path(__file__).resolve().parent
            for path in sorted(package.rglob("*.py")):
                h.update(path.relative_to(package).as_posix().encode() + b"\0")
                h.update(path.read_bytes() + b"\0")
            cls._code = h.hexdigest()[:12]
        return cls._code

    def path(self, stage: str, key: str) -> Path | None:
        return self.root / stage / f"{key}.{self.code_version()}.npz" if self.root else None

    def get(self, stage: str, key: str, compute: Callable[[], Any]) -> Any:
        path = self.path(stage, key)
        if path is not None and path.is_file():
            found, value = self._load(path)
            if found:
                self.reused.append(stage)
                return value
        value = compute()
        if path is not None and stage not in self.private and not self.read_only:
            try:
                payload = encode(value)
            except Unencodable:
                return value
            header = self.MAGIC + b" " + hashlib.sha256(payload).hexdigest().encode() + b"\n"
            try:
                artifacts.atomic_write(path, header + payload)
            except OSError as exc:
                if exc.errno not in READ_ONLY:
                    raise
                self.read_only = True  # the result stands; the next ones are not offered
        return value

    def _load(self, path: Path) -> tuple[bool, Any]:
        """``(True, value)`` for an intact entry; a damaged one is deleted: ``(False, None)``."""
        import warnings

        from ..errors import CacheWarning

        try:
            data = path.read_bytes()
        except OSError:
            return False, None
        header, _, payload = data.partition(b"\n")
        magic, _, digest = header.rpartition(b" ")
        problem = None
        if magic != self.MAGIC:
            problem = "it is not an icefarm cache entry of this format"
        elif hashlib.sha256(payload).hexdigest().encode() != digest:
            problem = "its bytes do not match the digest written with it"
        else:
            try:
                return True, decode(payload)
            except Exception as exc:  # intact bytes that do not decode: not an entry this code wrote
                problem = f"it does not load ({type(exc).__name__}: {exc})"
        message = f"stage cache entry {path} is damaged ({problem}): recomputed"
        self.warnings.append(message)
        warnings.warn(message, CacheWarning, stacklevel=2)
        try:
            path.unlink(missing_ok=True)
        except OSError:  # a read-only cache keeps it; it is never trusted all the same
            pass
        return False, None


def write_policy(root: Path, private: list[str]) -> bool:
    """Write ``root/policy.json`` naming the ``private`` stages (`StageCache`); False, with
    nothing written, when ``root`` is read-only to this user (a shared cache)."""
    try:
        root.mkdir(parents=True, exist_ok=True)
        artifacts.atomic_write(root / StageCache.POLICY, json.dumps({"private": list(private)}) + "\n")
    except OSError as exc:
        if exc.errno not in READ_ONLY:
            raise
        return False
    return True
