"""Timing reports of a sweep: the paper's Table 2 columns per job and per object.

`build_report` reads the artifacts of every job under a sweep folder (the job-folder contract of `icefarm.jobdir`,
its folders found by `icefarm.jobdir.scan_sweep`:
``jobs/<object id>/<job id>/`` with ``timings.json``, ``params.yaml`` and ``done.json`` or
``error.json``) and writes ``report.md`` and ``report.csv`` beside them.

Stage times are honest about the stage cache: a stage reused from the cache (the ``reused``
list of ``timings.json``) took only the time to read its entry back, so it shows as ``cached``, never
as a measured time; a job's Table 2 total then reads ``0.412 + cached``, and the per-object
medians are taken over the jobs that computed the stage.
"""

from __future__ import annotations

import csv
import io
import json
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import InputError
from .jobdir import (
    DONE,
    ERROR,
    JOBS_DIR,
    REPORT_CSV,
    REPORT_MD,
    SCENE_XML,
    TIMINGS,
    JobFolder,
    JobState,
    error_line,
    read_job,
    scan_sweep,
)

#: The stages of the paper's Table 2, in its order; their sum is its "Total time".
TABLE2_STAGES: tuple[str, ...] = ("water", "drips", "trajectories", "surface")
CACHED = "cached"


def stage_seconds(job: JobFolder, stage: str) -> float | None:
    """Seconds the stage computed for, None when it did not run or came from the cache."""
    value = job.seconds.get(stage)
    if stage in job.reused or not _is_number(value):
        return None
    return float(value)


def cached_stages(job: JobFolder) -> tuple[str, ...]:
    return tuple(s for s in TABLE2_STAGES if s in job.reused and s in job.seconds)


@dataclass(frozen=True)
class ObjectSummary:
    """Medians over one object's finished jobs.

    ``seconds`` holds, per stage, the median over the jobs that computed it (cached runs
    left out), or None when every job had it from the cache or none ran it; ``total`` is the
    sum of the Table 2 stage medians: what one uncached run of the object costs.
    """

    object_id: str
    done: int
    failed: int
    pending: int
    input_faces: float | None
    icicles: float | None
    ice_faces: float | None
    seconds: dict
    total: float | None
    cached_only: tuple
    render_variants: tuple


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def find_job_dirs(run_dir: Path) -> list[Path]:
    """Job folders under a sweep folder, in the order of its jobs.csv when it lists them
    (`icefarm.jobdir.scan_sweep`, the sheets' order too).

    ``run_dir`` may be a sweep folder (``jobs/<object>/<job>/``), any folder above job folders,
    or one job folder.
    """
    return list(scan_sweep(run_dir).job_dirs)


def summarize(jobs: Sequence[JobFolder]) -> list[ObjectSummary]:
    """Per-object medians, objects in the order they first appear in ``jobs``."""
    objects = list(dict.fromkeys(j.object_id for j in jobs))
    out = []
    for obj in objects:
        mine = [j for j in jobs if j.object_id == obj]
        done = [j for j in mine if j.state is JobState.DONE]
        seconds: dict[str, float | None] = {}
        for stage in ("prepare", "proxy", *TABLE2_STAGES, "render"):
            samples = [s for j in done if (s := stage_seconds(j, stage)) is not None]
            seconds[stage] = statistics.median(samples) if samples else None
        ran = [s for s in TABLE2_STAGES if any(s in j.seconds for j in done)]
        cached_only = tuple(s for s in ran if seconds[s] is None)
        measured = [seconds[s] for s in ran if seconds[s] is not None]
        out.append(ObjectSummary(
            object_id=obj,
            done=len(done),
            failed=sum(j.state is JobState.FAILED for j in mine),
            pending=sum(j.state is JobState.PENDING for j in mine),
            input_faces=_median_stat(done, "input_faces"),
            icicles=_median_stat(done, "icicles"),
            ice_faces=_median_stat(done, "ice_faces"),
            seconds=seconds,
            total=sum(measured) if measured else None,
            cached_only=cached_only,
            render_variants=tuple(dict.fromkeys(str(j.stats["render_variant"]) for j in done
                                                if j.stats.get("render_variant"))),
        ))
    return out


def _median_stat(jobs: Sequence[JobFolder], key: str) -> float | None:
    values = [float(j.stats[key]) for j in jobs if _is_number(j.stats.get(key))]
    return statistics.median(values) if values else None


def varied_params(jobs: Sequence[JobFolder]) -> list[str]:
    """Parameter keys whose values differ between the jobs (the swept ones), sorted."""
    keys = sorted({k for j in jobs for k in j.params or {}})
    return [k for k in keys
            if len({json.dumps(j.params.get(k), sort_keys=True, default=str) for j in jobs if j.params}) > 1]


# --------------------------------------------------------------------------- formatting

def fmt_seconds(value: float | None) -> str:
    """Seconds with three decimals below 10 s, one above; ``-`` for none."""
    if value is None:
        return "-"
    return f"{value:.3f}" if value < 10 else f"{value:.1f}"


def fmt_count(value: float | None) -> str:
    if value is None:
        return "-"
    return f"{value:,.0f}" if float(value).is_integer() else f"{value:,.1f}"


def _stage_cell(job: JobFolder, stage: str) -> str:
    if stage in job.reused and stage in job.seconds:
        return CACHED
    return fmt_seconds(stage_seconds(job, stage))


def _total_cell(job: JobFolder) -> str:
    if not any(s in job.seconds for s in TABLE2_STAGES):
        return "-"
    computed = sum(stage_seconds(job, s) or 0.0 for s in TABLE2_STAGES)
    return fmt_seconds(computed) + (f" + {CACHED}" if cached_stages(job) else "")


def _value_text(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return " ".join(_value_text(v) for v in value)
    return str(value)


def _md_escape(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _job_seconds(job: JobFolder) -> float:
    """Everything the job spent: preparation, proxy, stages (cache loads included), render."""
    return job.total_seconds or 0.0


_MD_JOB_HEADER = ("object", "job", "varied", "input polys", "icicles", "ice polys", "water s", "drips s",
                  "trajectories s", "surface s", "total s", "proxy s", "render s", "scene s", "variant", "job s")
_MD_SUMMARY_HEADER = ("object", "jobs", "failed", "input polys", "icicles", "ice polys", "water s",
                      "drips s", "trajectories s", "surface s", "total s", "proxy s", "render s", "variant")

CSV_COLUMNS = ("kind", "object", "job", "status", "varied", "input_faces", "flow_faces", "icicles", "branches",
               "ice_faces", "prepare_s", "proxy_s", "water_s", "drips_s", "trajectories_s", "surface_s",
               "total_s", "render_s", "mitsuba_s", "scene_s", "job_s", "render_variant", "render_integrator",
               "renderer", "cached", "jobs", "failed",
               "failed_stage", "error")


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    right = {i for i, h in enumerate(header) if h.endswith(" s") or h in ("input polys", "icicles", "ice polys",
                                                                           "jobs", "failed")}
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---:" if i in right else "---" for i in range(len(header))) + "|"]
    lines += ["| " + " | ".join(_md_escape(c) for c in row) + " |" for row in rows]
    return lines


def report_markdown(run_dir: Path, jobs: Sequence[JobFolder], summaries: Sequence[ObjectSummary]) -> str:
    """The Markdown report: per-object medians, per-job rows, failures."""
    varied = varied_params(jobs)
    done = [j for j in jobs if j.state is JobState.DONE]
    failed = [j for j in jobs if j.state is JobState.FAILED]
    pending = [j for j in jobs if j.state is JobState.PENDING]
    lines = [f"# Timing report: {Path(run_dir).name}", "",
             f"{len(jobs)} jobs: {len(done)} done, {len(failed)} failed, {len(pending)} not finished. "
             "Columns follow the paper's Table 2 (seconds per stage; total = water + drips + trajectories "
             "+ surface). `cached`: the stage was reused from the stage cache, so its time is not a "
             "measurement; a job's total then counts only the stages it computed (`+ cached`). "
             "Summary medians are taken over the jobs that computed each stage; the summary total is "
             "the sum of those medians, the cost of one uncached run. `render s` is the whole render "
             f"step, `scene s` its scene overhead (writing the scenes, loading {SCENE_XML}, waiting for the "
             "POV-Ray files). `job s` is everything the job spent (mesh preparation, proxy, stages, "
             "render).", ""]
    lines += ["## Per object (medians)", ""]
    lines += _md_table(_MD_SUMMARY_HEADER, [_summary_cells(s) for s in summaries])
    lines += ["", "## Per job", ""]
    rows = []
    for j in done:
        rows.append([j.object_id, j.job_id, _varied_text(j, varied), fmt_count(_stat(j, "input_faces")),
                     fmt_count(_stat(j, "icicles")), fmt_count(_stat(j, "ice_faces")),
                     *(_stage_cell(j, s) for s in TABLE2_STAGES), _total_cell(j), _stage_cell(j, "proxy"),
                     _stage_cell(j, "render"), fmt_seconds(_number(j.stats.get("scene_seconds"))),
                     str(j.stats.get("render_variant") or "-"),
                     fmt_seconds(_job_seconds(j))])
    lines += _md_table(_MD_JOB_HEADER, rows) if rows else ["No finished jobs."]
    if failed:
        lines += ["", "## Failed jobs", ""]
        lines += _md_table(("object", "job", "varied", "stage", "message"),
                           [[j.object_id, j.job_id, _varied_text(j, varied), j.failed_stage or "-",
                             _first_line(j.message)] for j in failed])
    if pending:
        lines += ["", f"## Not finished (no {DONE}, no {ERROR})", ""]
        lines += _md_table(("object", "job"), [[j.object_id, j.job_id] for j in pending])
    return "\n".join(lines) + "\n"


def _number(value: Any) -> float | None:
    return float(value) if _is_number(value) else None


def _first_line(message: str | None) -> str:
    return error_line(message)


def _stat(job: JobFolder, key: str) -> float | None:
    value = job.stats.get(key)
    return float(value) if _is_number(value) else None


def _varied_text(job: JobFolder, varied: Sequence[str]) -> str:
    values = job.params or {}
    return ", ".join(f"{k}={_value_text(values[k])}" for k in varied if k in values) or "-"


def _summary_cells(s: ObjectSummary) -> list[str]:
    def stage(name: str) -> str:
        if s.seconds.get(name) is None:
            return CACHED if name in s.cached_only else "-"
        return fmt_seconds(s.seconds[name])

    total = "-" if s.total is None else fmt_seconds(s.total) + (f" + {CACHED}" if s.cached_only else "")
    return [s.object_id, str(s.done), str(s.failed), fmt_count(s.input_faces), fmt_count(s.icicles),
            fmt_count(s.ice_faces), *(stage(n) for n in TABLE2_STAGES), total, stage("proxy"), stage("render"),
            ", ".join(s.render_variants) or "-"]


def report_csv(jobs: Sequence[JobFolder], summaries: Sequence[ObjectSummary]) -> str:
    """report.csv: one ``job`` row per job (failed and pending included), one ``object`` row per object.

    Stage cells hold seconds, or ``cached`` for a stage reused from the cache; ``total_s`` of
    a job counts the stages it computed, of an object the sum of its stage medians.
    """
    varied = varied_params(jobs)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()

    def csv_seconds(value: float | None) -> str:
        return "" if value is None else f"{value:.6g}"

    def csv_count(value: float | None) -> str:
        return "" if value is None else (str(int(value)) if float(value).is_integer() else f"{value:.1f}")

    for s in summaries:
        writer.writerow({
            "kind": "object", "object": s.object_id, "status": "median",
            "input_faces": csv_count(s.input_faces), "icicles": csv_count(s.icicles),
            "ice_faces": csv_count(s.ice_faces),
            **{f"{n}_s": (CACHED if n in s.cached_only else csv_seconds(s.seconds.get(n)))
               for n in ("prepare", "proxy", *TABLE2_STAGES, "render")},
            "total_s": csv_seconds(s.total), "render_variant": " ".join(s.render_variants),
            "cached": " ".join(s.cached_only), "jobs": s.done, "failed": s.failed,
        })
    for j in jobs:
        row: dict[str, Any] = {"kind": "job", "object": j.object_id, "job": j.job_id, "status": j.state.value,
                               "varied": _varied_text(j, varied)}
        for key in ("input_faces", "flow_faces", "icicles", "branches", "ice_faces"):
            row[key] = csv_count(_stat(j, key))
        for stage in ("prepare", "proxy", *TABLE2_STAGES, "render"):
            row[f"{stage}_s"] = (CACHED if stage in j.reused and stage in j.seconds
                                 else csv_seconds(stage_seconds(j, stage)))
        if j.state is JobState.DONE:
            row["total_s"] = csv_seconds(sum(stage_seconds(j, s) or 0.0 for s in TABLE2_STAGES))
            row["job_s"] = csv_seconds(_job_seconds(j))
        row.update(mitsuba_s=csv_seconds(_number(j.stats.get("render_seconds"))),
                   scene_s=csv_seconds(_number(j.stats.get("scene_seconds"))),
                   render_variant=j.stats.get("render_variant") or "",
                   render_integrator=j.stats.get("render_integrator") or "", renderer=j.stats.get("renderer") or "",
                   cached=" ".join(s for s in j.reused), failed_stage=j.failed_stage or "",
                   error=_first_line(j.message) if j.message else "")
        writer.writerow(row)
    return buf.getvalue()


def build_report(run_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.csv`` into ``run_dir`` from its job folders.

    Parameters
    ----------
    run_dir : Path
        A sweep folder (``<out>/<sweep name>/`` holding ``jobs/<object id>/<job id>/``), or
        one job folder.

    Returns
    -------
    (Path, Path)
        The Markdown and CSV files written.

    Raises
    ------
    InputError
        ``run_dir`` is not a folder or holds no job folders.
    """
    from .artifacts import atomic_write

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"report: {run_dir} is not a folder; give a sweep folder (<out>/<sweep name>)")
    job_dirs = find_job_dirs(run_dir)
    if not job_dirs:
        raise InputError(f"report: no job folders under {run_dir} (expected {JOBS_DIR}/<object>/<job id>/ "
                         f"with {TIMINGS}, {DONE} or {ERROR}); give a sweep folder")
    jobs = [read_job(d) for d in job_dirs]
    summaries = summarize(jobs)
    md_path, csv_path = run_dir / REPORT_MD, run_dir / REPORT_CSV
    atomic_write(md_path, report_markdown(run_dir, jobs, summaries))
    atomic_write(csv_path, report_csv(jobs, summaries))
    return md_path, csv_path
