"""The sweep folder on disk (its files: `icefarm.jobdir`): job folders, jobs.csv, manifest.resolved.yaml, and the rules
for an existing folder (``--resume``, ``--overwrite``) and the lock that keeps a second
sweep out of it.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import yaml

from ..errors import InputError
from ..jobdir import JOBS_DIR, MANIFEST, check_done, error_line
from .manifest import manifest_to_dict
from .manifest_model import Manifest
from .plan import JobRecord, PlannedJob


def job_dir(sweep_dir: Path, job: PlannedJob) -> Path:
    return sweep_dir / JOBS_DIR / job.object_id / job.job_id


def is_done(path: Path) -> bool:
    """The job in ``path`` finished and its artifacts are as done.json lists them."""
    return check_done(path) is None


def stale_folders(sweep_dir: Path, jobs: Sequence[PlannedJob]) -> list[Path]:
    """Job folders in ``sweep_dir/jobs`` that are no job of ``jobs`` (an edited manifest)."""
    planned = {job_dir(sweep_dir, j) for j in jobs}
    root = sweep_dir / JOBS_DIR
    if not root.is_dir():
        return []
    return sorted(p for p in root.glob("*/*") if p.is_dir() and p not in planned)


def _format(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return " ".join(_format(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def jobs_csv_text(records: Sequence[JobRecord], swept: Sequence[str]) -> str:
    """jobs.csv: one row per job, the swept values in their own columns."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["job_id", "object", *swept, "status", "seconds", "reused", "attempts",
                     "failed_stage", "error"])
    for r in records:
        values = dict(r.values)
        writer.writerow([r.job_id, r.object_id, *(_format(values.get(k, "")) for k in swept), r.status.value,
                         f"{r.seconds:.3f}", " ".join(r.reused), r.attempts, r.failed_stage or "",
                         error_line(r.error, "")])
    return buf.getvalue()


def resolved_yaml(manifest: Manifest, jobs: Sequence[PlannedJob], sweep_dir: Path, until: str | None) -> str:
    data = manifest_to_dict(manifest)
    data["until"] = until
    data["jobs"] = [{"id": j.job_id, "object": j.object_id, "seed": j.spec.seed,
                     "dir": str(job_dir(sweep_dir, j).relative_to(sweep_dir)),
                     "values": {k: v for k, v in j.values}} for j in jobs]
    return yaml.safe_dump(data, sort_keys=False)


def check_folder(sweep_dir: Path, resume: bool, overwrite: bool) -> bool:
    """Refuse what `prepare_folder` would refuse, deleting nothing; True when there is an
    existing sweep folder to keep (resume) or to delete (overwrite)."""
    if resume and overwrite:
        raise InputError("--resume and --overwrite exclude each other: resume keeps the done jobs, "
                         "overwrite deletes them")
    if sweep_dir.is_symlink():
        target = os.readlink(sweep_dir)
        if not sweep_dir.exists():
            raise InputError(f"output {sweep_dir} is a symbolic link to {target}, which does not exist: "
                             "remove the link or choose another -o")
        if overwrite:
            raise InputError(f"refusing to overwrite {sweep_dir}: it is a symbolic link (to {target}); "
                             "delete the link or what it points to yourself, or choose another -o")
    try:
        if not sweep_dir.exists() or (sweep_dir.is_dir() and not any(sweep_dir.iterdir())):
            return False
    except OSError as exc:
        raise InputError(f"cannot read the output folder {sweep_dir}: {exc.strerror or exc}") from None
    if not sweep_dir.is_dir():
        raise InputError(f"output {sweep_dir} exists and is not a folder")
    if resume:
        return True
    if not overwrite:
        raise InputError(f"output folder {sweep_dir} already exists: add --resume to finish its jobs "
                         f"(done ones are kept), --overwrite to delete it and start over, or choose -o")
    if not ((sweep_dir / MANIFEST).exists() or (sweep_dir / JOBS_DIR).is_dir()):
        raise InputError(f"refusing to overwrite {sweep_dir}: it does not look like an icefarm sweep folder "
                         f"(no {MANIFEST}, no {JOBS_DIR}/); remove it yourself or choose another -o")
    return True


def prepare_folder(sweep_dir: Path, resume: bool, overwrite: bool) -> None:
    """Refuse an existing sweep folder unless resuming; clear it for ``overwrite``."""
    if check_folder(sweep_dir, resume, overwrite) and overwrite:
        try:
            shutil.rmtree(sweep_dir)
        except OSError as exc:
            raise InputError(f"--overwrite: cannot delete {exc.filename or sweep_dir}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def sweep_lock(sweep_dir: Path) -> Iterator[None]:
    """Hold ``<out>/.<sweep name>.lock`` while this process writes ``sweep_dir``.

    A second sweep on the same folder (``--resume`` or ``--overwrite`` while the first runs)
    would delete the first's jobs under its workers; it is refused instead. The lock is a
    ``flock``: the system drops it when its process dies, so a killed sweep leaves none.
    The file sits beside the folder, which ``--overwrite`` deletes.

    Raises
    ------
    InputError
        Another process holds the lock.
    """
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    lock = sweep_dir.parent / f".{sweep_dir.name}.lock"
    try:
        sweep_dir.parent.mkdir(parents=True, exist_ok=True)
        fh = open(lock, "a+")
    except OSError as exc:
        raise InputError(f"cannot write the output folder {sweep_dir.parent}: "
                         f"{exc.strerror or exc} ({exc.filename or lock})") from None
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            raise InputError(f"another icefarm sweep (pid {holder}) is writing {sweep_dir}: wait for it "
                             "to end (then --resume), or choose another -o") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        try:
            yield
        finally:
            fh.truncate(0)  # an empty lock file names nobody
            fcntl.flock(fh, fcntl.LOCK_UN)


