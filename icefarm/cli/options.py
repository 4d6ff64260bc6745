"""Command-line values made into icefarm's: ``--set`` assignments, ``--exclude`` boxes, output folders."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError


def writable_folder(out: str | Path) -> Path:
    """``out``, created when missing; refused in one line when it cannot be written."""
    import tempfile

    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise InputError(f"cannot write the output folder {out}: {exc.strerror or exc}") from None
    return out


def readable_cache(cache: str | Path) -> Path:
    """``cache``, created when missing; one this user may read but not write (a studio's shared
    cache) is used read-only, said once on stderr; one that cannot be read is refused."""
    import click

    from ..job.cache import StageCache

    cache = Path(cache)
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot use the stage cache {cache}: {exc.strerror or exc}") from None
    if not os.access(cache, os.R_OK | os.X_OK):
        raise InputError(f"cannot read the stage cache {cache}: permission denied")
    if StageCache(cache).read_only:
        click.echo(f"note: the stage cache {cache} is read-only: its results are reused, the others computed "
                   "and not stored", err=True)
    return cache


def exclusion_box(text: str):
    """``--exclude``'s six numbers as a `icefarm.job.pipeline.Box`."""
    from ..job.pipeline import Box

    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 6:
        raise InputError(f"--exclude takes xmin,ymin,zmin,xmax,ymax,zmax in meters, got {text!r}")
    return Box(tuple(v[:3]), tuple(v[3:]))
