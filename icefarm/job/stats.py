"""A job's record of itself, `JobStats`: the seconds of each step, the steps taken from the
stage cache, and the figures its steps reported (each step's declared ``figures``, the
render's, the growth frames'); it writes ``timings.json`` and the body of ``done.json``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .. import artifacts
from ..errors import cannot_write
from ..jobdir import read_json

# Keys of timings.json that are the record's own, not a step's figures.
_OWN = ("seconds", "reused", "cache_warnings", "render_pending")


@dataclass(frozen=True)
class JobStats:
    """What a job measured about itself.

    Attributes
    ----------
    seconds : dict of str to float
        Each step's wall time, seconds (steps in the order they ran).
    figures : dict of str to Any
        The figures the steps reported (``icicles``, ``ice_faces``, ``glaze_p50_mm``, ...),
        JSON values; a later step's value for a key replaces an earlier one's.
    reused : tuple of str
        The steps whose results came from the stage cache.
    cache_warnings : tuple of str
        Cache entries found damaged and recomputed.
    render_pending : bool
        The stages ran and the render is still to come (`icefarm.job.pipeline.finish_render`).
    """

    seconds: dict[str, float] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    reused: tuple[str, ...] = ()
    cache_warnings: tuple[str, ...] = ()
    render_pending: bool = False

    def adding(self, figures: Mapping[str, Any]) -> JobStats:
        """This record with more figures."""
        return replace(self, figures={**self.figures, **figures})

    def as_json(self) -> dict[str, Any]:
        """``timings.json``'s content: ``seconds``, the figures, ``reused`` (and the cache's
        warnings and ``render_pending`` when there are any)."""
        out: dict[str, Any] = {"seconds": dict(self.seconds), **self.figures, "reused": list(self.reused)}
        if self.cache_warnings:
            out["cache_warnings"] = list(self.cache_warnings)
        if self.render_pending:
            out["render_pending"] = True
        return out

    def write(self, path: Path) -> None:
        """Write ``timings.json``; a folder that cannot take it is one line (`InputError`)."""
        write_record(path, self.as_json())

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> JobStats:
        return cls(seconds=dict(data.get("seconds") or {}),
                   figures={k: v for k, v in data.items() if k not in _OWN},
                   reused=tuple(data.get("reused") or ()), cache_warnings=tuple(data.get("cache_warnings") or ()),
                   render_pending=bool(data.get("render_pending")))

    @classmethod
    def read(cls, path: Path) -> JobStats:
        """The record in ``timings.json`` at ``path``."""
        return cls.from_json(read_json(path))


def write_record(path: Path, value: Mapping[str, Any]) -> None:
    """Write one of a job's records; a folder that cannot take it is one line (`InputError`)."""
    try:
        artifacts.write_json(path, dict(value))
    except OSError as exc:
        raise cannot_write(exc, f"the job folder {path.parent}") from None
