"""What a job's steps read and what they hand on: the job's inputs (`JobInputs`), the
results so far (`StageResults`), each stage's random stream (`stage_rng`).
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from ..mesh import PreparedMesh
from ..params import Params
from ..spatial import ray_caster
from ..stages import DripResult, TrajectoryResult, WaterResult


class Stage(enum.Enum):
    """The paper's stages: where a job can stop (``until``); RENDER is the pipeline's."""

    WATER = "water"
    DRIPS = "drips"
    TRAJECTORIES = "trajectories"
    SURFACE = "surface"
    RENDER = "render"


STAGE_ORDER = tuple(Stage)


def stage_rng(seed: int, stage: Stage, stream: int | None = None) -> np.random.Generator:
    """Each stage draws from its own stream, so a cached upstream stage changes nothing downstream."""
    key = [seed, STAGE_ORDER.index(stage)] + ([] if stream is None else [stream])
    return np.random.default_rng(key)


def stops(until: Stage | None, stage: Stage) -> bool:
    """Whether a chain asked to stop after ``until`` stops after ``stage``."""
    return until is not None and STAGE_ORDER.index(stage) >= STAGE_ORDER.index(until)


@dataclass(frozen=True)
class JobInputs:
    """What one run of the graph reads besides the results of its steps.

    Attributes
    ----------
    prepared : PreparedMesh
        The object, cleaned and in meters (`icefarm.mesh.prepare`).
    params : Params
        Resolved once (`icefarm.params.resolve`).
    seed : int
        Each stage draws from its own stream of this seed (`stage_rng`).
    placement : {"ground", "hanging"}
        A grounded object's icicles stop at the ground and its sole stays dry.
    exclude : tuple of ((3,), (3,))
        Boxes, in meters in the object's frame, where no icicle may hang.
    overrides : mapping
        Step name to a file whose contents replace that step's result (`icefarm.artifacts`).
    source : callable or None
        Returns the rain source mesh (or None for the sky); called inside the water step.
    mesh_key : str
        Identifies the mesh in the cache keys (the pipeline passes its content hash).
    note : callable or None
        ``note(text)``: what a long step is doing inside, for progress.
    """

    prepared: PreparedMesh
    params: Params
    seed: int = 0
    placement: str = "ground"
    exclude: tuple = ()
    overrides: Mapping[str, str | Path] = field(default_factory=dict)
    source: Callable[[], trimesh.Trimesh | None] | None = None
    mesh_key: str = ""
    note: Callable[[str], None] | None = None
    # One ray-tracing BVH per mesh, built by the first step that casts on it.
    casters: dict[int, Callable] = field(default_factory=dict, compare=False, repr=False)

    @property
    def mesh(self) -> trimesh.Trimesh:
        return self.prepared.mesh

    @property
    def gravity(self) -> np.ndarray:
        return self.params.gravity

    @property
    def physical(self) -> bool:
        """Whether the storm is in physical units (its groups read more parameters)."""
        return self.params.storm.mode == "physical"

    @functools.cached_property
    def proxy_reason(self) -> str | None:
        """Why stages 1-2 run on an approximate surface (paper 5.1), or None."""
        if self.params.proxy.mode == "never":
            return None
        from ..stages import proxy_reason

        return proxy_reason(self.prepared.problems, self.params.proxy.mode, self.params.proxy.face_budget)

    def caster(self, mesh: trimesh.Trimesh) -> Callable:
        """The ray caster of ``mesh``, built once per run."""
        if id(mesh) not in self.casters:
            self.casters[id(mesh)] = ray_caster(mesh)
        return self.casters[id(mesh)]


@dataclass(frozen=True)
class StageResults:
    """Every step's result, as far as the graph went (``until``).

    Attributes
    ----------
    mesh : trimesh.Trimesh
        The object, in meters: drip points lie on it, trajectories and bases grow from it.
    flow : trimesh.Trimesh
        The surface stages 1-2 ran on: ``mesh`` itself, the proxy's mesh, or either refined.
    proxy : ProxyResult or None
        The approximate surface, for problem meshes.
    water, drips, trajectories : stage results or None
    landing : LandingResult or None
        Where the water off the tips lands (``ground_ice.mode`` other than none).
    ground : GroundIce or None
        The mounds or stalagmites on the landing points.
    wet : CoatSurface or None
        The surface the glaze grows on and is measured on, with its water and its sole.
    ice : IceResult or None
        Stage 4, without measurements.
    measured : IceFigures or None
        Stage 4's plausibility figures, measured on its mesh.
    keys : dict
        Step name to the cache key its result was asked under.
    """

    mesh: trimesh.Trimesh
    flow: trimesh.Trimesh
    proxy: Any = None
    water: WaterResult | None = None
    drips: DripResult | None = None
    trajectories: TrajectoryResult | None = None
    landing: Any = None
    ground: Any = None
    wet: Any = None
    ice: Any = None
    measured: Any = None
    keys: dict = field(default_factory=dict)

    @property
    def proxy_reason(self) -> str | None:
        return None if self.proxy is None else self.proxy.reason
