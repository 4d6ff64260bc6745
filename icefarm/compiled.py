"""Compiling numeric loops that NumPy cannot vectorise (numba)."""

from __future__ import annotations


def compiled(**options):
    """``numba.njit`` without the GIL, cached where numba finds a folder it may write (the
    package's `__pycache__`, the user's cache folder, ``NUMBA_CACHE_DIR``); where it finds
    none, compiled anew in each process instead of failing at import."""
    import numba

    def compile(function):
        try:
            return numba.njit(cache=True, nogil=True, **options)(function)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return numba.njit(nogil=True, **options)(function)

    return compile
