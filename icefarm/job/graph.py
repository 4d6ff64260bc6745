"""A job's steps as one declared graph, in the spirit of a Dask graph: each `Step` says
once what it is called, which stage it belongs to, which steps and parameters it reads,
the function that computes it, the artifact it writes and the figures it reports. The
runner (`icefarm.job.runner`), the cache keys (`step_keys`) and what a sweep's jobs may
share (`share_digest`) are all derived from `STEPS`.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..params import Params
from . import figures, work
from .cache import digest, file_digest
from .records import JobInputs, Stage, StageResults


class Input(enum.Enum):
    """Job inputs a step's result depends on besides its parameters and upstream steps."""

    MESH = "mesh"  # the object's content, size and gravity (`JobInputs.mesh_key`)
    SEED = "seed"
    PLACEMENT = "placement"
    EXCLUDE = "exclude"
    OVERRIDE = "override"  # a file that replaces the step's result (`JobInputs.overrides`)


class When(enum.Enum):
    """When a step runs."""

    ALWAYS = "always"
    PROBLEM_MESH = "problem mesh"  # the mesh needs an approximate surface (`JobInputs.proxy_reason`)
    GROUND_ICE = "ground ice"  # ``ground_ice.mode`` is not none
    MEASURING = "measuring"  # the caller asked for figures (a job does, a benchmark does not)
    REFINING = "refining"  # a physical storm with ``storm.flow_edge`` set


@dataclass(frozen=True)
class Step:
    """One step of a job, declared once.

    Attributes
    ----------
    name : str
        The step's name: its cache folder, its timer and its progress line.
    stage : Stage
        The paper's stage it belongs to: a job asked to stop after a stage runs its steps
        and no later ones.
    compute : callable
        ``compute(inputs, results) -> value``, pure (`icefarm.job.work`).
    field : str
        The `StageResults` field its value fills.
    after : tuple of str
        The steps whose results it reads: its cache key holds theirs.
    reads : tuple of str
        Parameter groups (``"surface"``) or single parameters (``"glaze.lifetime"``) it reads.
    physical_reads : tuple of str
        Read only under a physical storm (``storm.mode``).
    inputs : tuple of Input
        Job inputs its result depends on.
    when : When
    cached : bool
        Whether its result is kept in the stage cache (a glue step is cheaper than reading it).
    timed : bool
        Whether it runs through the caller's ``step`` (timer, cache, progress) or bare.
    write : callable or None
        ``write(job_dir, results)``: its artifact in the job folder.
    figures : callable or None
        ``figures(inputs, results) -> dict``: what it reports in ``timings.json``.
    """

    name: str
    stage: Stage
    compute: Callable[[JobInputs, StageResults], Any]
    field: str
    after: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()
    physical_reads: tuple[str, ...] = ()
    inputs: tuple[Input, ...] = ()
    when: When = When.ALWAYS
    cached: bool = True
    timed: bool = True
    write: Callable[[Path, StageResults], None] | None = None
    figures: Callable[[JobInputs, StageResults], dict[str, Any]] | None = None


STEPS: tuple[Step, ...] = (
    Step("proxy", Stage.WATER, work.proxy, "proxy", reads=("proxy",), inputs=(Input.MESH,),
         when=When.PROBLEM_MESH, write=figures.write_proxy, figures=figures.proxy_figures),
    Step("flow", Stage.WATER, work.flow, "flow", after=("proxy",), inputs=(Input.MESH,), cached=False, timed=False),
    Step("refine", Stage.WATER, work.refine_flow, "flow", after=("flow",), reads=("storm.mode", "storm.flow_edge"),
         when=When.REFINING),
    Step("water", Stage.WATER, work.water, "water", after=("flow", "refine"), reads=("water",),
         physical_reads=("storm", "glaze.lifetime", "drips.drip_limit"), inputs=(Input.SEED, Input.OVERRIDE),
         write=figures.write_water, figures=figures.water_figures),
    Step("drips", Stage.DRIPS, work.drips, "drips", after=("water",), reads=("drips", "trajectories.length_scale"),
         physical_reads=("surface.tip_radius", "surface.growth_ratio", "surface.profile",
                         "trajectories.branch_spread", "trajectories.division_probability"),
         inputs=(Input.EXCLUDE, Input.PLACEMENT, Input.OVERRIDE), write=figures.write_drips,
         figures=figures.drips_figures),
    Step("trajectories", Stage.TRAJECTORIES, work.trajectories, "trajectories", after=("drips",),
         reads=("trajectories", "drips.drip_limit", "surface.tip_radius"), inputs=(Input.PLACEMENT, Input.OVERRIDE),
         write=figures.write_trajectories, figures=figures.trajectories_figures),
    Step("landing", Stage.SURFACE, work.landing, "landing", after=("trajectories",),
         reads=("ground_ice.runoff", "ground_ice.merge"), when=When.GROUND_ICE),
    Step("ground_ice", Stage.SURFACE, work.ground_ice, "ground", after=("landing",), reads=("ground_ice", "surface"),
         when=When.GROUND_ICE, cached=False, write=figures.write_landing, figures=figures.ground_ice_figures),
    Step("wet", Stage.SURFACE, work.wet, "wet", after=("water",),
         reads=("drips.ground_clearance", "glaze.mode"), inputs=(Input.PLACEMENT,), cached=False, timed=False),
    Step("surface", Stage.SURFACE, work.surface, "ice", after=("trajectories", "ground_ice", "wet"),
         reads=("surface", "glaze"), write=figures.write_ice, figures=figures.surface_figures),
    Step("measure", Stage.SURFACE, work.measure, "measured", after=("surface",), when=When.MEASURING, cached=False,
         figures=figures.measure_figures),
)

STEP_NAMES = tuple(s.name for s in STEPS)
SURFACE_STEP = next(s for s in STEPS if s.field == "ice")


def step(name: str) -> Step:
    """The declaration of step ``name``."""
    for s in STEPS:
        if s.name == name:
            return s
    raise KeyError(f"no step {name!r}; one of {', '.join(STEP_NAMES)}")


def overridable() -> tuple[str, ...]:
    """The steps whose result a file may replace."""
    return tuple(s.name for s in STEPS if Input.OVERRIDE in s.inputs)


def runs(s: Step, inputs: JobInputs, measuring: bool) -> bool:
    """Whether step ``s`` runs in this job."""
    if s.when is When.PROBLEM_MESH:
        return inputs.proxy_reason is not None
    if s.when is When.GROUND_ICE:
        return inputs.params.ground_ice.mode != "none"
    if s.when is When.MEASURING:
        return measuring
    if s.when is When.REFINING:
        return inputs.physical and inputs.params.storm.flow_edge > 0
    return True


def beside_render(inputs: JobInputs) -> tuple[Step, ...]:
    """The steps of this job that only measure and that no step reads: a job with a render
    runs them while it renders (on 2 cores the car's lookdev job takes about 1.5 s less)."""
    read = {a for s in STEPS for a in s.after}
    return tuple(s for s in STEPS if s.when is When.MEASURING and s.name not in read and runs(s, inputs, True))


def ancestors(name: str) -> tuple[Step, ...]:
    """Step ``name`` and every step it reads, directly or not, in graph order."""
    wanted = {name}
    for s in reversed(STEPS):
        if s.name in wanted:
            wanted.update(s.after)
    return tuple(s for s in STEPS if s.name in wanted)


def read_values(s: Step, params: Params) -> list[Any]:
    """The values of the parameters ``s`` reads, under the job's storm mode: whole groups
    as their dataclass, single parameters as ``[key, value]``."""
    physical = params.storm.mode == "physical"
    return [_value(params, key) for key in (*s.reads, *(s.physical_reads if physical else ()))]


def _value(params: Params, key: str) -> Any:
    group, _, name = key.partition(".")
    value = getattr(params, group)
    return [key, getattr(value, name)] if name else value


def _input_values(s: Step, inputs: JobInputs) -> list[Any]:
    values = {Input.MESH: inputs.mesh_key, Input.SEED: inputs.seed, Input.PLACEMENT: inputs.placement,
              Input.EXCLUDE: inputs.exclude,
              Input.OVERRIDE: file_digest(inputs.overrides[s.name]) if s.name in inputs.overrides else None}
    return [values[k] for k in s.inputs]


def step_keys(inputs: JobInputs, measuring: bool = True) -> dict[str, str | None]:
    """Each step's cache key: a digest of its name, its upstream steps' keys, the parameters
    it reads and its job inputs; None for a step that does not run in this job."""
    keys: dict[str, str | None] = {}
    for s in STEPS:
        if not runs(s, inputs, measuring):
            keys[s.name] = None
            continue
        keys[s.name] = digest(s.name, [keys[a] for a in s.after], read_values(s, inputs.params),
                              _input_values(s, inputs))
    return keys


def share_digest(name: str, params: Params, extra: Iterable[Any] = ()) -> str:
    """What jobs of one object must agree on to share step ``name``: the parameters it and
    the steps it reads declare, and ``extra`` (the object, its overrides). Jobs are compared
    on no more than the cache keys hold, so jobs that differ here never share the step."""
    return digest([read_values(s, params) for s in ancestors(name)], list(extra))


def cached_steps() -> tuple[str, ...]:
    return tuple(s.name for s in STEPS if s.cached)

