"""Test hook for farm workers: pause the jobs of one object, so that a test can kill the worker
process (or its driver) while it is inside a job.

Python imports ``sitecustomize`` at start-up from the first folder of ``sys.path`` that has
one, so every process started with this folder on ``PYTHONPATH`` runs this file: the driver,
the spawned workers of the local pool, and the Dask scheduler, nannies and workers. Tests get
that environment from `pause_env`. In such a process, once `icefarm.job.pipeline` is imported,
its ``run_job`` is wrapped: a job of object ``OBJECT_ID`` first touches ``<paused>/<pid>``
(when a folder is given), the event a test waits on, then sleeps ``SECONDS`` and runs. The
farm's worker looks ``pipeline.run_job`` up when it runs a job, so it calls the wrapper.

icefarm itself is not imported here: a worker sets its threads before the heavy imports.
"""

from __future__ import annotations

import functools
import importlib.abc
import importlib.machinery
import os
import sys
import time
from pathlib import Path

PAUSE_ENV = "ICEFARM_FARM_TEST_PAUSE"  # OBJECT_ID=SECONDS
PAUSED_ENV = "ICEFARM_FARM_TEST_PAUSED_DIR"  # where a paused worker touches a file named by its pid
HOOKS = Path(__file__).resolve().parent
TARGET = "icefarm.job.pipeline"


def pause_env(object_id: str, seconds: float, paused: Path | None = None) -> dict[str, str]:
    """Environment variables that make processes started with them pause the jobs of
    ``object_id`` for ``seconds``; with ``paused``, each paused worker first touches
    ``paused/<its pid>``."""
    path = os.pathsep.join(filter(None, [str(HOOKS), os.environ.get("PYTHONPATH")]))
    env = {"PYTHONPATH": path, PAUSE_ENV: f"{object_id}={seconds}"}
    if paused is not None:
        env[PAUSED_ENV] = str(paused)
    return env


def _pausing(run_job):
    target, _, seconds = os.environ.get(PAUSE_ENV, "").partition("=")

    @functools.wraps(run_job)
    def run(spec, *args, **kwargs):
        if spec.object_id == target:
            if os.environ.get(PAUSED_ENV):
                (Path(os.environ[PAUSED_ENV]) / str(os.getpid())).touch()
            time.sleep(float(seconds or 0))
        return run_job(spec, *args, **kwargs)

    return run


class _WrapOnImport(importlib.abc.MetaPathFinder):
    """Finds `icefarm.job.pipeline` as the normal path finder does, and wraps its ``run_job``
    right after the module ran."""

    def find_spec(self, name, path, target=None):
        if name != TARGET:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_and_wrap(module):
            exec_module(module)
            module.run_job = _pausing(module.run_job)

        spec.loader.exec_module = exec_and_wrap
        return spec


if __name__ == "sitecustomize" and os.environ.get(PAUSE_ENV):
    sys.meta_path.insert(0, _WrapOnImport())
