"""The jobs of a sweep: one per (object, sweep point), planned from a manifest, and what
became of each (`JobRecord`). Jobs of one object that agree on what a step reads (its
declaration, `icefarm.job.graph`) share that step through the cache; `leaders` and
`private_stages` say which.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import params as P
from ..errors import InputError, short_repr
from ..job import cached_steps, share_digest
from ..jobdir import JobState
from .manifest_model import Manifest
from .points import expand, swept_keys


@dataclass(frozen=True)
class PlannedJob:
    """One (object, sweep point) pair, ready to run.

    Attributes
    ----------
    spec : icefarm.job.pipeline.JobSpec
    job_id : str
        ``pipeline.job_id(spec)``; the job's folder name.
    object_id : str
    values : tuple
        ``((key, value), ...)``: this job's swept values, in sweep order.
    """

    spec: Any
    job_id: str
    object_id: str
    values: tuple


@dataclass(frozen=True)
class JobRecord:
    """What became of one job.

    Attributes
    ----------
    status : JobState
        ``done``, ``failed`` or ``pending`` (not run: a dry run, or an interrupted sweep).
    seconds : float
        Wall time the worker spent on the job (the sum of its recorded step times,
        `icefarm.jobdir.total_seconds`), 0 when not run.
    reused : tuple of str
        Stages taken from the cache.
    attempts : int
        Times the job was started (2 after a worker died under it).
    resumed : bool
        Already done before this run (``--resume``); not run again.
    """

    job_id: str
    object_id: str
    values: tuple
    job_dir: Path
    status: JobState = JobState.PENDING
    seconds: float = 0.0
    reused: tuple = ()
    attempts: int = 0
    resumed: bool = False
    failed_stage: str | None = None
    error: str | None = None


def job_seed(manifest_seed: int, object_id: str) -> int:
    """The seed of every job of one object: stable, from the manifest seed and the object id.

    All sweep points of an object share it, so that the stages a point does not change
    (water, drips, trajectories when sweeping the surface) are the same results, reused from
    the cache, and a contact sheet compares like with like.
    """
    digest = hashlib.sha256(f"icefarm:{manifest_seed}:{object_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def plan_jobs(manifest: Manifest, render: bool = True) -> tuple[tuple[PlannedJob, ...], int]:
    """One job per (object, sweep point), objects in manifest order, points in sweep order.

    Parameters
    ----------
    manifest : Manifest
    render : bool
        False drops the render config from every job (``--no-render``).

    Returns
    -------
    jobs : tuple of PlannedJob
    duplicates : int
        Points dropped because they repeat an earlier job exactly (same job id).

    Raises
    ------
    InputError
        A sweep point puts a parameter out of its domain together with the others.
    """
    from ..job.pipeline import JobSpec, job_id

    points = expand(manifest.sweep, manifest.seed)
    keys = swept_keys(manifest.sweep)
    jobs, seen, duplicates = [], set(), 0
    for obj in manifest.objects:
        for point in points:
            try:
                resolved = P.resolve(manifest.defaults, obj.params, point, manifest.fixed)
            except InputError as exc:
                raise InputError(f"{manifest.path}: object {obj.id}, sweep point {short_repr(point)}: "
                                 f"{exc}") from None
            spec = JobSpec(object_id=obj.id, mesh=obj.mesh, size_m=obj.size_m, params=resolved,
                           seed=job_seed(manifest.seed, obj.id),
                           render=manifest.render if render else None,
                           exclude=obj.exclude, overrides=obj.overrides, material=obj.material,
                           placement=obj.placement)
            jid = job_id(spec)
            if jid in seen:
                duplicates += 1
                continue
            seen.add(jid)
            jobs.append(PlannedJob(spec=spec, job_id=jid, object_id=obj.id,
                                   values=tuple((k, point[k]) for k in keys)))
    return tuple(jobs), duplicates


# Parameter groups that change how icicles and glaze look more than where they are: a sweep
# over them needs a view close enough to see it (`manifest_warnings`).
LOOK_GROUPS = ("surface", "trajectories", "glaze", "ground_ice")


def manifest_warnings(manifest: Manifest) -> list[str]:
    """What a valid manifest may not mean, one line each, said once for the whole sweep: the
    parameters it (or ``--set``) gives that its jobs' storm.mode does not read
    (`icefarm.params.idle_keys`), the objects' unlikely sizes (`icefarm.asset_io.size_hint`),
    and a sweep over the icicles' look rendered without a view that shows them."""
    from ..asset_io import size_hint

    swept = swept_keys(manifest.sweep)
    points = expand(manifest.sweep, manifest.seed) if "storm.mode" in swept else [{}]
    lines: dict[str, None] = {}
    for obj in manifest.objects:
        defaults, own, fixed = (P.flatten(layer or {}) for layer in (manifest.defaults, obj.params, manifest.fixed))
        keys = [*defaults, *own, *fixed, *swept]
        for point in points:  # the layers in the reverse of `plan_jobs`'s order: the last wins
            mode = next((layer["storm.mode"] for layer in (fixed, point, own, defaults) if "storm.mode" in layer),
                        P.lookup("storm.mode").default)
            lines.update(dict.fromkeys(P.idle_keys(keys, mode)))
        if obj.size_m is not None and (hint := size_hint(obj.size_m)):
            lines[f"object {obj.id}: {hint}"] = None
    shape = [k for k in swept if k.split(".")[0] in LOOK_GROUPS]
    if shape and manifest.render is not None:
        from ..scene.config import load_render_config

        config = load_render_config(manifest.render)
        if not any(view.frame == "ice" for view in config.views):
            lines[f"the sweep varies how icicles look ({', '.join(shape)}) but render config {config.name!r} "
                  f"has no ice view: at {config.width}x{config.height} the icicles are a few pixels wide and the "
                  "cells look alike; use render: lookdev (its second view zooms on the icicles)"] = None
    return list(lines)


def leaders(jobs: Sequence[PlannedJob]) -> dict[str, str]:
    """``{job id: id of the earlier job it waits for}``.

    Jobs of one object that agree on the water stage's inputs wait for the first of them:
    once it is done, its stage results are in the cache and the others reuse them instead of
    computing them again in parallel. Jobs with a different water stage do not wait.
    """
    first: dict[str, str] = {}
    out: dict[str, str] = {}
    for job in jobs:
        spec = job.spec
        key = share_digest("water", spec.params, [job.object_id, [list(o) for o in spec.overrides]])
        if key in first:
            out[job.job_id] = first[key]
        else:
            first[key] = job.job_id
    return out


def private_stages(jobs: Sequence[PlannedJob]) -> list[str]:
    """Cached steps whose result no two of ``jobs`` can share (`icefarm.job.share_digest`).

    The sweep's cache does not store them (``cache/policy.json``): a sweep over surface
    parameters would otherwise store every job's ice surface, which no other job reads.
    Jobs are compared on fewer inputs than the cache keys hold, so a stage that two jobs
    might share is always stored.
    """
    out = []
    for name in cached_steps():
        signatures = Counter(share_digest(name, j.spec.params, [j.object_id]) for j in jobs)
        if signatures and max(signatures.values()) == 1:
            out.append(name)
    return out


