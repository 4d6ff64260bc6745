"""Sweeps on a real Dask cluster: a `dask scheduler` and two `dask worker` processes on
127.0.0.1 (random ports), started from the venv's `dask` command and torn down afterwards."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from hooks.sitecustomize import pause_env

from icefarm.farm.manifest import load_manifest
from icefarm.farm.plan import plan_jobs
from icefarm.farm.sweep import SweepOptions, run_sweep
from icefarm.jobdir import JobState

pytestmark = pytest.mark.slow  # real processes, clusters and renders: `pytest -m "not slow"` skips them

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).parent / "dask"


@pytest.fixture(scope="module")
def paused(tmp_path_factory):
    """Where the cluster's workers say (a file named by their pid) that a job reached its pause."""
    return tmp_path_factory.mktemp("paused")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory, paused, wait_for):
    """Address of a scheduler with two single-threaded workers; everything stopped afterwards."""
    folder = tmp_path_factory.mktemp("dask")
    # The workers pause the jobs of "victim" (tests/hooks/sitecustomize.py), touching paused/<pid> first.
    env = dict(os.environ, DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="1", **pause_env("victim", 2, paused))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env["PYTHONPATH"]])
    with dask_processes(folder, wait_for, env) as (address, start):
        for i in range(2):
            start("worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard",
                  "--name", f"w{i}", "--death-timeout", "60", log=f"worker{i}.log")
        from distributed import Client

        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        yield address


def test_sweep_on_a_dask_cluster(tmp_path, cluster, write_manifest):
    path = write_manifest(grid={"trajectories.curve_angle": [1, 4], "surface.noise": [0.0, 0.001]}, name="d", seed=2,
                          objects=[{"id": "ball", "mesh": "ball.ply", "size_m": 0.3},
                                   {"id": "big", "mesh": "ball.ply", "size_m": 0.6}])
    summary = run_sweep(path, tmp_path / "out", SweepOptions(backend="dask", scheduler=cluster, until="trajectories"))
    assert summary.ok and summary.done == 8 and summary.backend == "dask"
    for r in summary.jobs:
        assert (r.job_dir / "done.json").is_file() and r.attempts == 1
    # Each object's later jobs waited for its first one: water and drips always come from the cache.
    leaders = {r.object_id: r for r in reversed(summary.jobs)}
    assert all({"water", "drips"} <= set(r.reused) for r in summary.jobs if leaders[r.object_id] is not r)
    resumed = run_sweep(path, tmp_path / "out",
                        SweepOptions(backend="dask", scheduler=cluster, until="trajectories", resume=True))
    assert resumed.resumed == 8 and resumed.ok
    # the sweep set up the cluster's workers for its jobs: no stack sampler holding the GIL
    from distributed import Client

    with Client(cluster, timeout=30) as client:
        sampling = client.run(lambda dask_worker: "profile" in dask_worker.periodic_callbacks)
        assert len(sampling) == 2 and not any(sampling.values())


def test_dask_reschedules_the_job_of_a_killed_worker(tmp_path, cluster, paused, write_manifest, wait_for):
    path = write_manifest(grid={"drips.count": [2, 3]}, name="d", seed=2,
                          objects=[{"id": "victim", "mesh": "ball.ply", "size_m": 0.3},
                                   {"id": "ball", "mesh": "ball.ply", "size_m": 0.4}])
    victim = plan_jobs(load_manifest(path), render=False)[0][0].job_id
    marker = tmp_path / "out" / "d" / ".farm" / "running" / f"{victim}.pid"
    killed = []

    def kill_once():
        pid = wait_for(lambda: marker.is_file() and marker.read_text().split(), "the victim job", 60)[0]
        wait_for(lambda: (paused / pid).exists(), "the victim job to reach its pause", 60)
        os.kill(int(pid), signal.SIGKILL)
        killed.append(pid)

    killer = threading.Thread(target=kill_once)
    killer.start()
    summary = run_sweep(path, tmp_path / "out", SweepOptions(backend="dask", scheduler=cluster, until="drips"))
    killer.join()
    assert killed
    records = {r.job_id: r for r in summary.jobs}
    assert records[victim].status is JobState.DONE and records[victim].attempts == 2
    assert summary.done == 4 and summary.ok


def test_dask_without_a_scheduler_starts_a_local_cluster(tmp_path, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3]}, name="d", seed=2)
    summary = run_sweep(path, tmp_path / "out", SweepOptions(backend="dask", workers=2, until="drips"))
    assert summary.ok and summary.done == 2 and summary.workers == 2
    assert summary.jobs[1].reused == ("refine", "water")


@contextlib.contextmanager
def dask_processes(folder: Path, wait_for, env: dict | None = None):
    """``(address, start)``: a `dask scheduler` on 127.0.0.1 started in ``folder``, and
    ``start(*args, log=...)`` to start more `dask` processes (workers), all with ``env``
    (default: this one, icefarm's checkout first on the path); all of them (whole process
    groups) stopped afterwards."""
    if not DASK.exists():
        pytest.skip(f"no dask command at {DASK}")
    if env is None:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    procs = []

    def start(*args, log):
        procs.append(subprocess.Popen([str(DASK), *args], env=env, cwd=folder, start_new_session=True,
                                      stdout=(folder / log).open("w"), stderr=subprocess.STDOUT))

    try:
        info = folder / "scheduler.json"
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(info), log="scheduler.log")
        yield wait_for(lambda: info.is_file() and json.loads(info.read_text() or "{}").get("address"),
                       "the scheduler", 60), start
    finally:
        for proc in reversed(procs):
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


def test_a_sweep_says_when_its_cluster_has_no_workers(tmp_path, write_manifest, wait_for):
    """A scheduler without workers: the sweep says it waits (and for what) instead of sitting
    silent, and says when a worker joined."""
    with dask_processes(tmp_path, wait_for) as (address, start):
        path = write_manifest(grid={"drips.count": [2, 3]}, name="d", seed=2)
        notes: list[str] = []
        result: list = []
        options = SweepOptions(backend="dask", scheduler=address, until="water")
        sweep = threading.Thread(target=lambda: result.append(run_sweep(path, tmp_path / "out", options,
                                                                        note=notes.append)))
        sweep.start()
        wait_for(lambda: any("no workers" in n for n in notes), "the sweep to say it waits", 60)
        assert f"dask worker {address}" in notes[0]
        start("worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard", "--name", "late",
              log="worker.log")
        sweep.join(timeout=300)
        assert result and result[0].ok and result[0].done == 2
        assert any("1 worker joined" in n for n in notes), notes


def test_renders_run_on_the_gpu_worker_and_stages_on_the_other(tmp_path, write_manifest, sweep_kit, wait_for):
    """One worker declares the GPU resource, one does not: every job's render runs on the
    first as soon as its stages are done, every job's stages on the second."""
    from distributed import Client, get_task_stream

    with dask_processes(tmp_path, wait_for) as (address, start):
        for name, extra in (("gpu", ["--resources", "GPU=1"]), ("cpu", [])):
            start("worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard", "--name", name,
                  *extra, log=f"{name}.log")
        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
            path = write_manifest(grid={"drips.count": [2, 3]}, name="g", seed=2,
                                  render=str(sweep_kit.tiny_render(tmp_path)))
            with get_task_stream(client) as stream:  # the scheduler records which worker ran what
                summary = run_sweep(path, tmp_path / "out", SweepOptions(backend="dask", scheduler=address))
            names = {a: w["name"] for a, w in client.scheduler_info()["workers"].items()}
            ran = {s["key"]: names[s["worker"]] for s in stream.data if str(s["key"]).startswith("icefarm-")}
    assert summary.ok and summary.done == 2, [r.error for r in summary.jobs]
    stages = {k: w for k, w in ran.items() if k.startswith("icefarm-stages-")}
    renders = {k: w for k, w in ran.items() if k not in stages}
    assert len(stages) == 2 and set(stages.values()) == {"cpu"}, ran
    assert len(renders) == 2 and set(renders.values()) == {"gpu"}, ran
    for r in summary.jobs:
        timings = json.loads((r.job_dir / "timings.json").read_text())
        assert (r.job_dir / "render.png").is_file() and (r.job_dir / "done.json").is_file()
        assert {"surface", "render", "usd"} <= set(timings["seconds"]) and "render_pending" not in timings


def test_dask_workers_that_ran_pymeshlab_exit_cleanly(tmp_path):
    # a box-modelled asset: refining its flow surface runs pymeshlab in a task's thread
    import yaml

    manifest = tmp_path / "m.yaml"
    objects = [{"id": "shelter", "mesh": "generator:shelter"}]
    manifest.write_text(yaml.safe_dump({"name": "m", "seed": 1, "objects": objects, "sweep": {
        "method": "grid", "parameters": {"storm.intensity": {"values": ["light"]}}}}))
    result = subprocess.run([sys.executable, "-m", "icefarm.cli", "sweep", str(manifest), "-o", str(tmp_path / "out"),
                             "--backend", "dask", "--workers", "1", "--until", "water"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "1 done" in result.stdout
    # glibc's words when a worker aborted on exit with its heap corrupted
    assert "malloc" not in result.stderr and "corrupted" not in result.stderr, result.stderr
