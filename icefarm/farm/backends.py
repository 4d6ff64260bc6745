"""Run jobs in worker processes: a local spawn pool, or a Dask cluster.

Both backends take the same `Task` list and report each job's `JobOutcome` through a
callback as it finishes. A job's failure is the pipeline's business (it writes error.json and
returns "failed"); what the backends handle is a worker dying under a job (killed, out of
memory, a crash in native code):

- local: a dead worker breaks the whole ``ProcessPoolExecutor`` and fails every job then in
  flight, without saying whose worker died. The jobs that had not started are queued again;
  the ones that had started (their marker file says so) are each retried once, alone in a
  fresh one-process pool, so that a second death is that job's own: it is then marked failed.
  A new pool runs the rest.
- dask: the scheduler reschedules a dead worker's task; after ``allowed-failures`` deaths it
  gives up with ``KilledWorker`` and the job is marked failed. A LocalCluster started here
  allows one retry; an external scheduler follows its own setting
  (``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1`` for the same policy).

This module imports nothing heavy at the top: a spawned worker imports it before its
initializer runs, and the thread settings must come first.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
import traceback
import uuid
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

# Test hook: "OBJECT_ID=SECONDS" makes that object's jobs sleep after they started (so a test
# can kill the worker mid-job). With PAUSED_ENV naming a folder, a paused worker first touches
# PID there: the test kills on that event instead of sleeping into the pause and hoping.
PAUSE_ENV = "ICEFARM_FARM_TEST_PAUSE"
PAUSED_ENV = "ICEFARM_FARM_TEST_PAUSED_DIR"
_BLAS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class Task:
    """One job as a worker receives it.

    Attributes
    ----------
    spec : icefarm.pipeline.JobSpec
    job_id, object_id : str
    job_dir : str
        Folder the job writes; emptied before each attempt.
    cache_dir : str or None
        Stage cache shared by the sweep.
    until : str or None
        Last stage to run (a `Stage` value).
    running_dir : str
        Where the worker leaves ``<job id>.pid`` (one line per attempt) while it runs.
    threads : int or None
        Dr.Jit / BLAS threads for the worker (its share of the cores).
    job_fn : callable or None
        Replaces ``pipeline.run_job`` (tests).
    """

    spec: Any
    job_id: str
    object_id: str
    job_dir: str
    cache_dir: str | None
    until: str | None
    running_dir: str
    threads: int | None = None
    job_fn: Callable | None = None


# --------------------------------------------------------------------------- in the worker

def _marker(task: Task) -> Path:
    return Path(task.running_dir) / f"{task.job_id}.pid"


def attempts_started(task: Task) -> int:
    """How many times a worker started ``task`` in this sweep run without finishing it yet."""
    try:
        return len(_marker(task).read_text().split())
    except OSError:
        return 0


def failed_outcome(message: str, stage: str | None = None, trace: str = ""):
    """A `JobOutcome` for a job that the farm, not the pipeline, saw fail."""
    from ..pipeline import JobOutcome

    return JobOutcome(status="failed", seconds={}, reused=(), failed_stage=stage,
                      error=message + ("\n" + trace if trace else ""))


def write_error(job_dir: str | Path, message: str, stage: str | None = None, trace: str = "") -> None:
    """error.json as the pipeline writes it, for failures outside the pipeline."""
    from ..artifacts import write_json
    from ..jobdir import ERROR

    write_json(Path(job_dir) / ERROR, {"stage": stage, "message": message, "traceback": trace})


def execute(task: Task) -> tuple[Any, int]:
    """Run one job in this worker process.

    Returns
    -------
    outcome : JobOutcome
    attempt : int
        1 for the first start of the job, 2 after a worker died under it, ...
    """
    marker = _marker(task)
    marker.parent.mkdir(parents=True, exist_ok=True)
    with marker.open("a") as fh:  # one line per attempt: a leftover line means a dead worker
        fh.write(f"{os.getpid()}\n")
    attempt = attempts_started(task)
    _test_pause(task)
    job_dir = Path(task.job_dir)
    if job_dir.exists():  # leftovers of an attempt that did not finish
        shutil.rmtree(job_dir)
    job_dir.mkdir(parents=True)
    try:
        from .. import pipeline

        if task.spec.render is not None and task.threads:
            from ..scene.variants import set_thread_count

            set_thread_count(task.threads)
        run = task.job_fn or pipeline.run_job
        until = pipeline.Stage(task.until) if task.until else None
        cache = Path(task.cache_dir) if task.cache_dir else None
        outcome = run(task.spec, job_dir, cache_dir=cache, until=until)
    except Exception as exc:  # run_job reports job failures itself; this is a farm-level bug
        trace = traceback.format_exc()
        write_error(job_dir, f"{type(exc).__name__}: {exc}", None, trace)
        outcome = failed_outcome(f"{type(exc).__name__}: {exc}", None, trace)
    marker.unlink(missing_ok=True)
    return outcome, attempt


def _test_pause(task: Task) -> None:
    spec = os.environ.get(PAUSE_ENV, "")
    target, _, seconds = spec.partition("=")
    if target and target == task.object_id:
        if os.environ.get(PAUSED_ENV):
            (Path(os.environ[PAUSED_ENV]) / str(os.getpid())).touch()
        time.sleep(float(seconds or 0))


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


# --------------------------------------------------------------------------- scheduling

class _Gate:
    """Hands out tasks in order, holding back each task until the one it waits for is done."""

    def __init__(self, tasks: Sequence[Task], waits: Mapping[str, str]):
        self.queue = deque(tasks)
        self.waits = dict(waits)
        self.finished: set[str] = set()

    def __bool__(self) -> bool:
        return bool(self.queue)

    def next(self) -> Task | None:
        for i, task in enumerate(self.queue):
            leader = self.waits.get(task.job_id)
            if leader is None or leader in self.finished:
                del self.queue[i]
                return task
        return None

    def requeue(self, task: Task) -> None:
        self.queue.appendleft(task)

    def finish(self, task: Task) -> None:
        self.finished.add(task.job_id)


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def threads_per_worker(workers: int) -> int:
    return max(1, cores() // max(1, workers))


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


OnOutcome = Callable[[Task, Any, int], None]


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
    gate = _Gate(tasks, waits or {})

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


def _deliver(fut, task: Task, on_outcome: OnOutcome, gate: _Gate) -> bool:
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
                _marker(task).unlink(missing_ok=True)
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


# --------------------------------------------------------------------------- dask

def check_scheduler_address(address: str) -> None:
    """Refuse what is no Dask scheduler address before anything tries to reach it.

    Raises
    ------
    InputError
        Not ``[scheme://]host:port`` with a scheme Dask knows (tcp, tls, ws, ...).
    """
    from ..errors import InputError, short_repr

    try:
        from distributed.comm import registry
        from distributed.comm.addressing import parse_address, parse_host_port

        scheme, location = parse_address(address)
        registry.get_backend(scheme)
        if scheme != "inproc":
            host, port = parse_host_port(location)
            if not host or not 0 < int(port) < 65536:
                raise ValueError("expected a host and a port from 1 to 65535")
    except ImportError:
        return
    except (ValueError, TypeError) as exc:
        raise InputError(f"--scheduler {short_repr(address)} is not a Dask scheduler address ({exc}): "
                         f"expected tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786") from None


@contextlib.contextmanager
def dask_client(workers: int, scheduler: str | None = None, connect_timeout: float = 30.0) -> Iterator[Any]:
    """A `distributed.Client` of the scheduler at ``scheduler``, or of a LocalCluster of
    ``workers`` single-threaded worker processes started (and stopped) here.

    Raises
    ------
    InputError
        A bad address, or no scheduler answering there within ``connect_timeout`` seconds.
    """
    import dask
    from distributed import Client, LocalCluster

    from ..errors import InputError

    cluster = client = None
    try:
        if scheduler is None:
            with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
            client = Client(cluster)
        else:
            check_scheduler_address(scheduler)
            try:
                with dask.config.set({"distributed.comm.timeouts.connect": f"{connect_timeout}s"}):
                    client = Client(scheduler, timeout=connect_timeout)
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler} within {connect_timeout:g} s "
                                 f"({type(exc).__name__}: {_first_line(exc)}): is `dask scheduler` running "
                                 f"there? nothing was written") from None
        yield client
    finally:
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else "no answer"


def _worker_count(client) -> int:
    try:
        return len(client.scheduler_info().get("workers", {}))
    except Exception:
        return -1


@contextlib.contextmanager
def _watch_workers(client, address: str, note: Callable[[str], None], every: float = 2.0,
                   remind: float = 60.0) -> Iterator[None]:
    """Say when the cluster has no worker to run the jobs (and when workers join), instead
    of a sweep that sits silent; a reminder every ``remind`` seconds while it waits."""
    import threading

    stop = threading.Event()
    waiting = [None]

    def check() -> None:
        n = _worker_count(client)
        now = time.monotonic()
        if n == 0 and waiting[0] is None:
            waiting[0] = now
            note(f"dask: the scheduler at {address} has no workers: the jobs wait for one to join "
                 f"(start them with `dask worker {address}`)")
        elif n == 0 and now - waiting[0] >= remind:
            note(f"dask: still waiting for a worker to join the scheduler at {address} "
                 f"({(now - waiting[0]) / 60:.0f} min)")
            waiting[0] = now
        elif n > 0 and waiting[0] is not None:
            waiting[0] = None
            note(f"dask: {n} worker{'s' * (n != 1)} joined the scheduler at {address}: running")

    def loop() -> None:
        while not stop.wait(every):
            check()

    check()
    thread = threading.Thread(target=loop, name="icefarm-dask-workers", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=every + 5)
        if waiting[0] is not None and not thread.is_alive():
            check()  # workers that came and did the work between two looks


def run_dask(tasks: Sequence[Task], *, workers: int, on_outcome: OnOutcome,
             scheduler: str | None = None, waits: Mapping[str, str] | None = None,
             connect_timeout: float = 30.0, client=None,
             note: Callable[[str], None] | None = None) -> None:
    """Run ``tasks`` on a Dask cluster: ``client``'s, or the scheduler at ``scheduler``, or
    a LocalCluster of ``workers`` single-threaded worker processes started (and stopped) here.

    The workers must import icefarm and see the sweep folder at the same path (one machine, or
    a shared file system). ``note(text)`` hears when the cluster has no workers (and when
    they join). Other parameters as `run_local`.
    """
    if client is None:
        with dask_client(workers, scheduler, connect_timeout) as own:
            return run_dask(tasks, workers=workers, on_outcome=on_outcome, scheduler=scheduler, waits=waits,
                            client=own, note=note)
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    threads = threads_per_worker(workers) if scheduler is None else None
    run = uuid.uuid4().hex[:8]
    gate = _Gate([replace(t, threads=threads) for t in tasks], waits or {})
    futures: dict[str, Task] = {}
    live: dict[str, Any] = {}
    stream = as_completed()

    def submit_ready() -> None:
        while (task := gate.next()) is not None:
            fut = client.submit(execute, task, key=f"icefarm-{task.job_id}-{run}", pure=False)
            futures[fut.key] = task
            live[fut.key] = fut
            stream.add(fut)

    watch = (_watch_workers(client, scheduler, note) if scheduler is not None and note is not None
             else contextlib.nullcontext())
    try:
        with watch:
            submit_ready()
            for fut in stream:
                task = futures.pop(fut.key)
                live.pop(fut.key, None)
                try:
                    outcome, attempt = fut.result()
                except KilledWorker:
                    attempt = max(1, attempts_started(task))
                    message = (f"the worker running this job died {attempt} times (killed, out of memory, or a "
                               f"crash in native code); the scheduler gave up on it (allowed-failures)")
                    write_error(task.job_dir, message)
                    outcome = failed_outcome(message)
                except Exception as exc:
                    attempt = max(1, attempts_started(task))
                    message = f"{type(exc).__name__}: {exc}"
                    write_error(task.job_dir, message, None, traceback.format_exc())
                    outcome = failed_outcome(message)
                fut.release()
                _marker(task).unlink(missing_ok=True)
                gate.finish(task)
                on_outcome(task, outcome, attempt)
                submit_ready()
            if gate:
                raise RuntimeError("farm: tasks wait for each other in a cycle")  # a planning bug
    except BaseException:
        # Stopped (a signal, an error): the jobs not yet started are taken off the cluster. A
        # job already running on an external cluster's worker cannot be stopped by Dask: it
        # finishes there (a --resume redoes it unless it wrote done.json).
        with contextlib.suppress(Exception):
            client.cancel(list(live.values()), force=True)
        raise
