"""Reading a sweep folder into a `RunInfo`: its jobs, their parameters, states and order."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from .. import params as P
from ..errors import InputError
from ..jobdir import JOBS_DIR, read_job, scan_sweep
from .labels import sort_key, varying_keys
from .model import JobInfo, JobState, RunInfo

# reading

def scan_run(run_dir: Path, sweep_name: str | None = None) -> RunInfo:
    """Read a sweep folder: every job of every object, in job order.

    The folder is scanned as the report scans it (`icefarm.jobdir.scan_sweep`). Job order
    is the order of ``jobs.csv`` when it exists (jobs it does not list follow, sorted by
    their varying values); otherwise the jobs sorted by their varying values.

    Raises
    ------
    InputError
        ``run_dir`` has no ``jobs/`` folder.
    """
    run_dir = Path(run_dir)
    found = scan_sweep(run_dir)
    if not found.is_sweep:
        raise InputError(f"{run_dir} is not a sweep folder: it has no {JOBS_DIR}/ folder "
                         f"(give the folder `icefarm sweep` wrote, <out>/<sweep name>)")
    manifest = found.manifest()
    name = sweep_name or str(manifest.get("name") or run_dir.name)
    sweep = manifest.get("sweep") if isinstance(manifest.get("sweep"), Mapping) else {}
    method = sweep.get("method") if isinstance(sweep.get("method"), str) else None
    csv_rows, swept = found.rows, found.swept

    objects: dict[str, dict[str, JobInfo]] = {}
    for job_dir in sorted(found.job_dirs):  # by object, then job: the objects' order
        folder = read_job(job_dir)
        obj = job_dir.parent.name
        objects.setdefault(obj, {})[job_dir.name] = JobInfo(
            object_id=obj, job_id=job_dir.name, path=job_dir, state=folder.state,
            values=folder.params or {}, has_params=folder.params is not None, folder=folder)
    csv_order: dict[str, list[str]] = {}
    for row in csv_rows:
        obj, job = row.get("object") or "", row["job_id"]
        csv_order.setdefault(obj, []).append(job)
        known = objects.setdefault(obj, {})
        if job in known:
            if not known[job].has_params:  # fall back on the swept values jobs.csv lists
                known[job] = _with_values(known[job], _csv_values(row, swept))
        elif obj:
            known[job] = JobInfo(object_id=obj, job_id=job, path=None, state=JobState.PENDING,
                                 values=_csv_values(row, swept), has_params=False)

    ordered: dict[str, list[JobInfo]] = {}
    for obj, jobs in objects.items():
        if not jobs:
            continue
        vary = varying_keys(list(jobs.values()), swept)
        first = [jobs[j] for j in dict.fromkeys(csv_order.get(obj, [])) if j in jobs]
        listed = {j.job_id for j in first}
        rest = sorted((j for j in jobs.values() if j.job_id not in listed),
                      key=lambda j: (tuple(sort_key(j.values.get(k)) for k in vary), j.job_id))
        ordered[obj] = first + rest
    return RunInfo(run_dir=run_dir, name=name, method=method, swept=swept, objects=ordered)


def _with_values(job: JobInfo, values: dict) -> JobInfo:
    return JobInfo(job.object_id, job.job_id, job.path, job.state, values, False, job.folder)


def _csv_values(row: Mapping[str, str], swept: Sequence[str]) -> dict:
    out = {}
    for key in swept:
        raw = row.get(key, "")
        if raw:
            value = P.parse_value(raw)
            # jobs.csv writes vectors as "0 -1 0"
            if isinstance(value, str) and all(_is_number(t) for t in value.split()):
                value = [float(t) for t in value.split()]
            out[key] = value
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
