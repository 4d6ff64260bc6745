"""Which Mitsuba variant renders, and the libLLVM and thread pool it runs on.

Dr.Jit starts its LLVM backend when it is imported, loading whatever libLLVM it finds;
Debian's LLVM 15 and 16 then abort the whole process on the first render and 14 is
refused. So `pick_variant` finds a libLLVM of version 17 or newer itself and sets
``DRJIT_LIBLLVM_PATH`` *before* drjit is imported, and uses ``llvm_ad_rgb`` only when the
library Dr.Jit actually loaded is a good one.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path

from ..errors import InputError

MIN_LLVM = 17
LLVM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
             "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib")
_LLVM_NAME = re.compile(r"^libLLVM(?:-(?P<a>\d+)[\w.]*?)?\.(?:so|dylib)(?:\.(?P<b>\d+)[\d.]*)?$")
# Measured (Mitsuba 3.9): with a one-thread Dr.Jit pool, reading any EXR (the sky) waits forever,
# so a process pinned to one core (taskset, a one-CPU container) hangs in its first scene load.
MIN_POOL_THREADS = 2


def llvm_version(path: str | Path) -> int | None:
    """Major LLVM version of a ``libLLVM`` file from its name (after symlinks), or None.

    ``libLLVM-15.so.1`` -> 15, ``libLLVM.so.19.1`` -> 19, ``libLLVM-17.so`` -> 17; a bare
    ``libLLVM.so`` counts only if it resolves to a versioned name or sits in ``llvm-N/lib``.
    """
    path = Path(path)
    for candidate in (path, path.resolve() if path.exists() else path):
        match = _LLVM_NAME.match(candidate.name)
        if match and (match["a"] or match["b"]):
            return int(match["a"] or match["b"])
    for part in reversed(path.parts[:-1]):
        m = re.fullmatch(r"llvm-(\d+)", part)
        if m and _LLVM_NAME.match(path.name):
            return int(m[1])
    return None


def find_libllvm(search_dirs: Iterable[str | Path] | None = None,
                 minimum: int = MIN_LLVM) -> Path | None:
    """The newest ``libLLVM`` of version >= ``minimum`` in ``search_dirs``, or None.

    Parameters
    ----------
    search_dirs : iterable of paths, optional
        Folders to look in; default `LLVM_DIRS`, ``/usr/lib/llvm-*/lib`` and
        ``LD_LIBRARY_PATH``.
    """
    if search_dirs is None:
        dirs = [Path(d) for d in os.environ.get("LD_LIBRARY_PATH", "").split(":") if d]
        dirs += [Path(d) for d in LLVM_DIRS]
        dirs += sorted(Path("/usr/lib").glob("llvm-*/lib"))
    else:
        dirs = [Path(d) for d in search_dirs]
    best: tuple[int, Path] | None = None
    for d in dirs:
        if not d.is_dir():
            continue
        for f in sorted(d.glob("libLLVM*")):
            version = llvm_version(f)
            if version is not None and version >= minimum and f.is_file() \
                    and (best is None or version > best[0]):
                best = (version, f)
    return None if best is None else best[1]


def loaded_libllvm() -> list[Path]:
    """libLLVM files mapped into this process (from ``/proc/self/maps``; empty elsewhere)."""
    try:
        text = Path("/proc/self/maps").read_text()
    except OSError:
        return []
    return sorted({Path(line.split(None, 5)[5]) for line in text.splitlines()
                   if "libLLVM" in line and len(line.split(None, 5)) == 6})


def prepare_llvm(search_dirs: Iterable[str | Path] | None = None) -> Path | None:
    """Point ``DRJIT_LIBLLVM_PATH`` at a good libLLVM before drjit is imported.

    Keeps a user's ``DRJIT_LIBLLVM_PATH`` if it names a good one; otherwise sets the newest
    good one found, or, when there is none, a path that does not exist, so that Dr.Jit
    leaves its LLVM backend off instead of picking a bad library by itself. Does nothing
    (returns what is set) once drjit is imported, since Dr.Jit reads it only then.

    Returns
    -------
    Path or None
        The good libLLVM now named, or None.
    """
    current = os.environ.get("DRJIT_LIBLLVM_PATH")
    good_current = bool(current) and Path(current).is_file() and (llvm_version(current) or 0) >= MIN_LLVM
    if "drjit" in sys.modules:
        return Path(current) if good_current else None
    if good_current and search_dirs is None:
        return Path(current)
    found = find_libllvm(search_dirs)
    os.environ["DRJIT_LIBLLVM_PATH"] = str(found) if found else "/nonexistent/icefarm-no-good-libLLVM.so"
    return found


def choose_variant(requested: str, cuda: bool, llvm: bool) -> str:
    """The variant for ``requested`` given which backends work; `InputError` if it cannot run.

    ``auto`` takes cuda_ad_rgb, then llvm_ad_rgb, then scalar_rgb.
    """
    if requested == "auto":
        return "cuda_ad_rgb" if cuda else "llvm_ad_rgb" if llvm else "scalar_rgb"
    if requested == "cuda_ad_rgb" and not cuda:
        raise InputError("variant cuda_ad_rgb asked for, but no working CUDA GPU was found: "
                         "use variant: auto or llvm_ad_rgb")
    if requested == "llvm_ad_rgb" and not llvm:
        raise InputError(f"variant llvm_ad_rgb asked for, but no libLLVM {MIN_LLVM} or newer is "
                         "loaded (install libllvm19, or set DRJIT_LIBLLVM_PATH to one before "
                         "starting): use variant: auto or scalar_rgb")
    if requested not in ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"):
        raise InputError(f"unknown variant {requested!r}: use auto, scalar_rgb, llvm_ad_rgb or cuda_ad_rgb")
    return requested


def pick_variant(requested: str = "auto", search_dirs: Iterable[str | Path] | None = None) -> str:
    """Resolve ``requested`` to a Mitsuba variant that works in this process.

    Sets up ``DRJIT_LIBLLVM_PATH`` first (see `prepare_llvm`), then imports drjit and asks
    it which backends started. LLVM counts only if every libLLVM mapped into the process
    is of version 17 or newer. Dr.Jit's pool gets at least `MIN_POOL_THREADS` threads.

    Raises
    ------
    InputError
        An explicit variant whose backend does not work here.
    """
    prepare_llvm(search_dirs)  # also for scalar_rgb: importing drjit starts LLVM regardless
    import drjit as dr

    set_thread_count()
    if requested == "scalar_rgb":
        return requested
    cuda = bool(dr.has_backend(dr.JitBackend.CUDA)) if requested in ("auto", "cuda_ad_rgb") else False
    llvm = bool(dr.has_backend(dr.JitBackend.LLVM))
    if llvm and Path("/proc/self/maps").exists():  # trust only what was really loaded
        loaded = loaded_libllvm()
        llvm = bool(loaded) and all((llvm_version(p) or 0) >= MIN_LLVM for p in loaded)
    return choose_variant(requested, cuda, llvm)


def set_thread_count(threads: int | None = None) -> int:
    """Size Dr.Jit's thread pool, which renders and loads scenes, importing drjit if needed.

    Parameters
    ----------
    threads : int, optional
        Threads wanted (a farm worker's share of the cores); default Dr.Jit's own choice,
        one per core this process may use. Never fewer than `MIN_POOL_THREADS`.

    Returns
    -------
    int
        The pool's size now.
    """
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    prepare_llvm()  # Dr.Jit picks its libLLVM when imported
    import drjit as dr

    wanted = max(MIN_POOL_THREADS, threads or dr.thread_count())
    if dr.thread_count() != wanted:
        dr.set_thread_count(wanted)
    return wanted
