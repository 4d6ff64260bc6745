"""Run farm jobs in a local pool of spawned worker processes.

A dead worker (killed, out of memory, a crash in native code) breaks the whole
``ProcessPoolExecutor`` and fails every job then in flight, without saying whose worker died.
The jobs that had not started are queued again; the ones that had started (their marker file
says so) are each retried once, alone in a fresh one-process pool, so that a second death is
that job's own: it is then marked failed. A new pool runs the rest.

This module imports nothing heavy at the top: a spawned worker imports it (for `_worker_init`)
before its initializer runs, and the thread settings must come first.
"""

from __future__ import annotations

import contextlib
import os
import time
import traceback
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from typing import Any

from .task import (
    Gate,
    OnOutcome,
    Task,
    attempts_started,
    execute,
    failed_outcome,
    marker_path,
    threads_per_worker,
    write_error,
)

_BLAS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
WATCHDOG_S = 0.5  # how often a local worker checks that its driver is still there


def _worker_init(driver: int) -> None:
    """Initializer of every local worker process.

    Ctrl-C is the driver's to handle (it ends the workers), so a worker ignores SIGINT. A
    worker ends by itself when its driver is gone (SIGKILL, the OOM killer), instead of
    running on with parent pid 1 and writing jobs that a later ``--resume`` also writes:
    on Linux the kernel kills it (``PR_SET_PDEATHSIG``), elsewhere a thread notices.
    """
    import signal
    import sys
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm's default lock is a multiprocessing semaphore, named and left to the resource
    # tracker: a worker killed on Ctrl-C never unlinks it, and the driver's exit then warns of
    # a "leaked semaphore". A worker's bars are its own: a thread lock is enough.
    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            PR_SET_PDEATHSIG = 1
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != driver:  # the driver died before the line above took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == driver:
            time.sleep(WATCHDOG_S)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="icefarm-driver-watch", daemon=True).start()


@contextlib.contextmanager
def _child_environment(threads: int) -> Iterator[None]:
    """Environment that spawned workers inherit: their thread share (restored afterwards)."""
    wanted = {k: str(threads) for k in _BLAS_ENV if k not in os.environ}
    saved = {k: os.environ.get(k) for k in wanted}
    os.environ.update(wanted)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def run_local(tasks: Sequence[Task], *, workers: int, on_outcome: OnOutcome,
              waits: Mapping[str, str] | None = None, max_tasks_per_child: int = 8) -> None:
    """Run ``tasks`` in a pool of ``workers`` spawned processes.

    Parameters
    ----------
    tasks : sequence of Task
        In the order to start them.
    workers : int
    on_outcome : callable
        ``on_outcome(task, outcome, attempts)``, called in this process as each job ends.
    waits : mapping, optional
        ``{job id: job id}``: a task starts only after that other task ended.
    max_tasks_per_child : int
        A worker is replaced by a fresh process after this many jobs.
    """
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    threads = threads_per_worker(workers)
    tasks = [replace(t, threads=threads) for t in tasks]
    gate = Gate(tasks, waits or {})

    def new_pool(n: int) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=n, mp_context=ctx, max_tasks_per_child=max_tasks_per_child,
                                   initializer=_worker_init, initargs=(os.getpid(),))

    with _child_environment(threads):
        pool = new_pool(workers)
        inflight: dict[Any, Task] = {}
        try:
            while gate or inflight:
                broken = False
                while len(inflight) < workers and not broken:
                    task = gate.next()
                    if task is None:
                        break
                    try:
                        inflight[pool.submit(execute, task)] = task
                    except BrokenProcessPool:
                        gate.requeue(task)
                        broken = True
                if not inflight and not broken:
                    raise RuntimeError("farm: tasks wait for each other in a cycle")  # a planning bug
                if inflight and not broken:
                    done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                    for fut in done:
                        if _deliver(fut, inflight[fut], on_outcome, gate):
                            del inflight[fut]
                        else:
                            broken = True
                if broken:
                    # Every job in flight fails with the pool; report those that finished first.
                    wait(list(inflight))
                    lost = [t for f, t in inflight.items() if not _deliver(f, t, on_outcome, gate)]
                    inflight.clear()
                    pool.shutdown(wait=True, cancel_futures=True)
                    for task in reversed([t for t in lost if attempts_started(t) == 0]):
                        gate.requeue(task)  # never started: not a suspect
                    started = [t for t in lost if attempts_started(t) > 0]
                    for task, outcome, attempt in _isolated(started, workers, ctx):
                        gate.finish(task)
                        on_outcome(task, outcome, attempt)
                    pool = new_pool(workers)
        except BaseException:
            _kill_workers(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _deliver(fut, task: Task, on_outcome: OnOutcome, gate: Gate) -> bool:
    """Report a finished future; False when it failed because the pool broke."""
    try:
        outcome, attempt = fut.result()
    except BrokenProcessPool:
        return False
    except Exception as exc:  # e.g. the task could not be pickled
        message = f"{type(exc).__name__}: {exc}"
        write_error(task.job_dir, message, None, traceback.format_exc())
        outcome, attempt = failed_outcome(message), 1
    gate.finish(task)
    on_outcome(task, outcome, attempt)
    return True


def _isolated(tasks: Sequence[Task], workers: int, ctx) -> Iterator[tuple[Task, Any, int]]:
    """Retry each task alone in its own one-process pool (up to ``workers`` at once), so that
    a pool that breaks again names its job; yields ``(task, outcome, attempts)``."""
    queue = deque(tasks)
    active: dict[Any, tuple[Task, ProcessPoolExecutor]] = {}
    try:
        while queue or active:
            while queue and len(active) < workers:
                task = queue.popleft()
                pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_init,
                                           initargs=(os.getpid(),))
                active[pool.submit(execute, task)] = (task, pool)
            done, _ = wait(active, return_when=FIRST_COMPLETED)
            for fut in done:
                task, pool = active.pop(fut)
                attempt = attempts_started(task)
                try:
                    outcome, attempt = fut.result()
                except BrokenProcessPool:
                    message = (f"the worker process running this job died {attempts_started(task)} times "
                               f"(killed, out of memory, or a crash in native code); it was retried once")
                    write_error(task.job_dir, message)
                    outcome = failed_outcome(message)
                except Exception as exc:
                    message = f"{type(exc).__name__}: {exc}"
                    write_error(task.job_dir, message, None, traceback.format_exc())
                    outcome = failed_outcome(message)
                pool.shutdown(wait=True)
                marker_path(task).unlink(missing_ok=True)
                yield task, outcome, attempt
    finally:
        for _, pool in active.values():
            _kill_workers(pool)
            pool.shutdown(wait=False, cancel_futures=True)


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    """Stop a pool's processes now (on Ctrl-C or an error), not after their jobs."""
    for proc in list(getattr(pool, "_processes", {}).values()):  # no public API for this
        with contextlib.suppress(Exception):
            proc.kill()
