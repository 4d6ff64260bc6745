"""Run farm jobs on a Dask cluster: an external scheduler's, or a LocalCluster started here.

The scheduler reschedules the task of a worker that died under it (killed, out of memory, a
crash in native code); after ``allowed-failures`` deaths it gives up with ``KilledWorker`` and
the job is marked failed. A LocalCluster started here allows one retry; an external scheduler
follows its own setting (``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1`` for the same policy).
"""

from __future__ import annotations

import contextlib
import logging
import time
import traceback
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from typing import Any

from .task import (
    Gate,
    OnOutcome,
    Task,
    attempts_started,
    execute,
    execute_geometry,
    execute_render,
    failed_outcome,
    marker_path,
    threads_per_worker,
    write_error,
)

# The Dask worker resource that marks a render machine (`dask worker --resources GPU=1`): where
# a cluster has such workers, each job's render runs on one of them as soon as its stages are
# done, and the stages run on the others.
RENDER_RESOURCE = "GPU"


# What glibc's own dynamic limits reach at most on 64-bit Linux, bytes: arrays below the first
# come from the heap, which keeps up to the second free for the next ones.
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 64 << 20


def _reuse_heap() -> None:
    """Let this process's large temporary arrays reuse freed heap (glibc ``mallopt``).

    Dask's nannies start workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which fixes glibc's
    thresholds low: every array over 128 KiB is mapped and unmapped, and faulted in again.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None)
        m_trim_threshold, m_mmap_threshold = -1, -3
        libc.mallopt(m_mmap_threshold, MMAP_THRESHOLD)
        libc.mallopt(m_trim_threshold, TRIM_THRESHOLD)


def _worker_plugin():
    """A Dask `WorkerPlugin` that sets a worker up for icefarm's jobs, on every worker of the
    cluster, those that join later too.

    Under Dask's defaults a job runs markedly slower than in the local pool (`icefarm bench
    farm --backend local --backend dask`; docs/sweeps.md): its profiler samples each running
    task's stack 100 times a second, holding the GIL, and its heap settings (`_reuse_heap`)
    fault large arrays in again and again. It also loads pymeshlab in the worker's main
    thread, without which the worker aborts as it exits.
    """
    from distributed.diagnostics.plugin import WorkerPlugin

    class JobWorker(WorkerPlugin):
        name = "icefarm-job-worker"

        def setup(self, worker) -> None:
            for key in ("profile", "profile-cycle"):
                callback = worker.periodic_callbacks.pop(key, None)
                if callback is not None:
                    callback.stop()
            _reuse_heap()
            # pymeshlab (Qt) first loaded in a task's thread corrupts glibc's heap as the
            # worker exits ("malloc_consolidate(): unaligned fastbin chunk detected", SIGABRT);
            # loaded here, in the worker's main thread, it exits cleanly.
            import pymeshlab  # noqa: F401

    return JobWorker()


def worker_roles(client) -> tuple[list[str], list[str]]:
    """``(render, stages)``: the addresses of the cluster's workers that declare
    `RENDER_RESOURCE` and of the others."""
    try:
        workers = client.scheduler_info().get("workers", {})
    except Exception:
        return [], []
    render = [a for a, w in workers.items() if (w.get("resources") or {}).get(RENDER_RESOURCE, 0) > 0]
    return render, [a for a in workers if a not in render]


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
             scheduler: str | None = None, waits: Mapping[str, str] | None = None, client=None,
             note: Callable[[str], None] | None = None) -> None:
    """Run ``tasks`` on a Dask cluster: ``client``'s, or the scheduler at ``scheduler``, or
    a LocalCluster of ``workers`` single-threaded worker processes started (and stopped) here.

    Where the cluster has workers that declare `RENDER_RESOURCE`, each job with a render runs
    in two tasks: its stages on the other workers, its render (`icefarm.job.pipeline.finish_render`)
    on a render worker, which starts it as soon as the stages are done.

    The workers must import icefarm and see the sweep folder at the same path (one machine, or
    a shared file system). ``note(text)`` hears when the cluster has no workers (and when
    they join). Other parameters as `run_local`.
    """
    if client is None:
        with dask_client(workers, scheduler) as own:
            return run_dask(tasks, workers=workers, on_outcome=on_outcome, scheduler=scheduler, waits=waits,
                            client=own, note=note)
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    from ..job.pipeline import Stage, renders_apart

    threads = threads_per_worker(workers) if scheduler is None else None
    run = uuid.uuid4().hex[:8]
    client.register_plugin(_worker_plugin())
    gate = Gate([replace(t, threads=threads) for t in tasks], waits or {})
    futures: dict[str, Task] = {}
    live: dict[str, Any] = {}
    stream = as_completed()

    def submit_ready() -> None:
        while (task := gate.next()) is not None:
            render_workers, stage_workers = worker_roles(client)
            # stages stay off the render machines where there are others to run them
            placed = {"workers": stage_workers, "allow_other_workers": False} if render_workers and stage_workers \
                else {}
            until = Stage(task.until) if task.until else None
            if render_workers and renders_apart(task.spec, until):
                stages = client.submit(execute_geometry, task, key=f"icefarm-stages-{task.job_id}-{run}", pure=False,
                                       **placed)
                live[stages.key] = stages
                fut = client.submit(execute_render, task, stages, key=f"icefarm-{task.job_id}-{run}", pure=False,
                                    resources={RENDER_RESOURCE: 1})
            else:
                fut = client.submit(execute, task, key=f"icefarm-{task.job_id}-{run}", pure=False, **placed)
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
                stages = live.pop(f"icefarm-stages-{task.job_id}-{run}", None)
                if stages is not None:
                    stages.release()
                marker_path(task).unlink(missing_ok=True)
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
