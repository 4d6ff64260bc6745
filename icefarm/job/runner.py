"""The one runner of the declared graph (`icefarm.job.graph.STEPS`): a job, a sweep's
worker, the benchmarks, Table 2, growth frames and the tests all run a job's steps
through `run_graph`, so what they measure is what a job runs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection
from typing import Any

from .graph import STEPS, Step, overridable, runs, step_keys
from .records import STAGE_ORDER, JobInputs, Stage, StageResults

Work = Callable[[], Any]
StepRunner = Callable[[Step, "str | None", Work], Any]
"""``step(declaration, key, work)`` runs ``work`` for a step and returns its result; ``key``
names the result in a cache (None: not to be cached)."""


def _bare(s: Step, key: str | None, work: Work) -> Any:
    return work()


def run_graph(inputs: JobInputs, *, until: Stage | None = None, step: StepRunner = _bare,
              on_step: Callable[[Step, StageResults], None] | None = None, measuring: bool = False,
              skip: Collection[str] = ()) -> StageResults:
    """Run the declared steps on ``inputs`` in order, up to the stage ``until``.

    Parameters
    ----------
    inputs : JobInputs
    until : Stage, optional
        Stop after this stage's steps.
    step : callable
        ``step(declaration, key, work)`` runs each timed step: a cache, a timer or both.
        Glue steps (``timed`` False) run bare.
    on_step : callable, optional
        ``on_step(declaration, results)`` after each step, with the results so far: where the
        caller writes the step's artifact and figures.
    measuring : bool
        Run the steps that only measure (`When.MEASURING`).
    skip : collection of str
        Steps left to the caller, which runs them with `run_step` (a job runs those no step
        reads beside its render: `graph.beside_render`).

    Returns
    -------
    StageResults
    """
    bad = set(inputs.overrides) - set(overridable())
    if bad:
        raise ValueError(f"no override for {sorted(bad)}; one of {', '.join(overridable())}")
    keys = step_keys(inputs, measuring)
    results = StageResults(mesh=inputs.mesh, flow=inputs.mesh)
    last = None if until is None else STAGE_ORDER.index(until)
    for s in STEPS:
        if last is not None and STAGE_ORDER.index(s.stage) > last:
            break
        if s.name in skip or not runs(s, inputs, measuring):
            continue
        value = run_step(s, inputs, results, step, keys[s.name])
        results = dataclasses.replace(results, keys={**results.keys, s.name: keys[s.name]}, **{s.field: value})
        if on_step is not None:
            on_step(s, results)
    return results


def run_step(s: Step, inputs: JobInputs, results: StageResults, step: StepRunner = _bare,
             key: str | None = None) -> Any:
    """One declared step on ``results``: through ``step`` (cached under ``key`` where the
    step is cached), or bare for a glue step."""
    def work() -> Any:
        return s.compute(inputs, results)

    if not s.timed:
        return work()
    return step(s, key if s.cached else None, work)


def run_stages(prepared: Any, params: Any, seed: int = 0, *, until: Stage | None = None,
               step: StepRunner = _bare, **job: Any) -> StageResults:
    """The graph on a prepared mesh with a job's inputs (`JobInputs` fields as keywords:
    ``placement``, ``exclude``, ``overrides``, ``source``, ``mesh_key``), no figures: what
    a benchmark, Table 2 and the tests run."""
    return run_graph(JobInputs(prepared, params, seed, **job), until=until, step=step)
