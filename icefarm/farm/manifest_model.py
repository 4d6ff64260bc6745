"""The sweep manifest as data: objects, the sweep, and the manifest holding them.

Frozen dataclasses built by `icefarm.farm.manifest.parse_manifest` once every value in them has
been validated; below that boundary they are trusted.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class SweepMethod(enum.Enum):
    GRID = "grid"      # every combination of the parameters' values
    ZIP = "zip"        # the i-th value of every parameter together
    RANDOM = "random"  # `count` points drawn at random


class Distribution(enum.Enum):
    UNIFORM = "uniform"
    LOG_UNIFORM = "log_uniform"  # min and max are values, as W&B's log_uniform_values


@dataclass(frozen=True)
class Axis:
    """One swept parameter: a list of values, or a range for random sweeps.

    Attributes
    ----------
    key : str
        ``group.name`` of the parameter.
    values : tuple
        Validated values (empty for a range).
    low, high : float or None
        The range for random draws, in the parameter's unit.
    distribution : Distribution or None
        How a range is drawn.
    """

    key: str
    values: tuple = ()
    low: float | None = None
    high: float | None = None
    distribution: Distribution | None = None


@dataclass(frozen=True)
class Sweep:
    """The sweep section: ``method`` over ``axes``; ``product`` axes (from ``--set a,b``)
    are crossed with the method's points as a grid."""

    method: SweepMethod
    axes: tuple[Axis, ...]
    count: int | None = None
    product: tuple[Axis, ...] = ()


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a manifest, with paths made absolute.

    Attributes
    ----------
    id : str
        Folder-safe name, unique in the manifest.
    mesh : str
        Absolute path of a mesh file, or ``generator:NAME``.
    size_m : float
        Height of the bounding box, in meters.
    params : dict
        Flat ``{"group.name": value}``, validated; over the manifest's defaults.
    exclude : tuple of Box
        Where no icicle may hang (`icefarm.job.pipeline.Box`), in meters, object frame.
    overrides : tuple
        ``((stage, absolute path), ...)`` files replacing a stage's result.
    material : Material or None
        For rendering (`icefarm.scene.material.Material`); None for the default.
    placement : str
        ``ground`` (stands on the ground plane) or ``hanging``.
    """

    id: str
    mesh: str
    size_m: float
    params: dict = field(default_factory=dict)
    exclude: tuple = ()
    overrides: tuple = ()
    material: Any = None
    placement: str = "ground"


@dataclass(frozen=True)
class Manifest:
    """A validated manifest. ``defaults`` and object ``params`` are flat ``{"group.name": v}``;
    ``fixed`` holds command-line overrides that win over everything else."""

    path: Path
    name: str
    seed: int
    render: str | None
    defaults: dict
    objects: tuple[ObjectSpec, ...]
    sweep: Sweep | None = None
    fixed: dict = field(default_factory=dict)
