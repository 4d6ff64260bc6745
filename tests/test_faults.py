"""Faults a farm must survive: its driver killed (no orphaned workers, a --resume that finishes),
corrupted stage-cache entries and job folders (recomputed, never trusted), and file modes
on a shared output folder. Real processes and real signals; stage-only jobs on a tiny mesh."""

import json
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from hooks.sitecustomize import pause_env

from icefarm import params
from icefarm.artifacts import atomic_write
from icefarm.errors import CacheWarning
from icefarm.farm.sweep import SweepOptions, run_sweep
from icefarm.job.cache import StageCache
from icefarm.job.pipeline import JobSpec, Stage, run_job

pytestmark = pytest.mark.slow  # real processes, clusters and renders: `pytest -m "not slow"` skips them

ICEFARM = Path(sys.executable).parent / "icefarm"
def session_processes(sid: int) -> set[int]:
    """Live (not zombie) processes of session ``sid``."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, session, ...
        if int(fields[3]) == sid and fields[0] != "Z":
            found.add(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return state[state.rindex(")") + 2] != "Z"


_KILLED_WORKER = """
import os, sys, time, multiprocessing
from concurrent.futures import ProcessPoolExecutor
from icefarm.farm.local import _worker_init, _kill_workers

def bar():
    from tqdm import tqdm
    tqdm(total=1, disable=True).close()  # as a job's render and growth bars do
    time.sleep(60)

if __name__ == "__main__":
    init = _worker_init if sys.argv[1] == "icefarm" else None
    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=init,
                               initargs=(os.getpid(),) if init else ())
    pool.submit(bar)
    time.sleep(8)
    _kill_workers(pool)
    pool.shutdown(wait=True, cancel_futures=True)
"""


@pytest.mark.slow  # spawns worker processes
def test_a_worker_killed_on_ctrl_c_leaks_no_semaphore(tmp_path):
    # tqdm's default lock is a named semaphore: a worker killed with one made it leak, and the
    # driver's exit printed Python's "leaked semaphore objects" warning after the summary.
    script = tmp_path / "killed.py"
    script.write_text(_KILLED_WORKER)
    plain = subprocess.run([sys.executable, str(script), "plain"], capture_output=True, text=True, timeout=120)
    ours = subprocess.run([sys.executable, str(script), "icefarm"], capture_output=True, text=True, timeout=120)
    assert "leaked semaphore" in plain.stderr  # the check sees the leak when there is one
    assert ours.returncode == 0 and "leaked" not in ours.stderr, ours.stderr


# --------------------------------------------------------------------------- the driver killed

@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("signum,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGKILL, None)],
                         ids=["SIGTERM", "SIGINT", "SIGKILL"])
def test_a_killed_driver_leaves_no_process_and_resume_finishes_every_job(tmp_path, signum, code, write_manifest,
                                                                         wait_for):
    path = write_manifest(grid={"water.rays": [300, 301, 302]})
    out = tmp_path / "out"
    env = dict(os.environ, **pause_env("ball", 600))  # every job stays in its worker
    # As from a terminal: a sweep keeps ignoring a signal it was started ignoring (nohup), and
    # a test run started in the background by a shell ignores SIGINT, which the driver inherits.
    driver = subprocess.Popen([str(ICEFARM), "sweep", str(path), "-o", str(out), "--workers", "2",
                               "--until", "drips"], env=env, cwd=tmp_path, start_new_session=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        running = out / "t" / ".farm" / "running"
        markers = wait_for(lambda: len(list(running.glob("*.pid"))) >= 2 and list(running.glob("*.pid")),
                           "two jobs in their workers")
        workers = {int(m.read_text().split()[0]) for m in markers}
        assert len(workers) == 2 and driver.pid not in workers
        os.kill(driver.pid, signum)
        stdout, stderr = driver.communicate(timeout=120)
        if code is not None:
            assert driver.returncode == code, stderr
            assert f"interrupted by {signal.Signals(signum).name}" in stderr and "--resume" in stderr
            assert "Traceback" not in stderr
        else:
            assert driver.returncode == -signal.SIGKILL
        # Ended by the driver, or by themselves once it is gone: nothing of the sweep is left.
        wait_for(lambda: not session_processes(driver.pid), "every process of the sweep to end", timeout=30)
        assert not any(alive(pid) for pid in workers)
    finally:
        for pid in session_processes(driver.pid):
            os.kill(pid, signal.SIGKILL)
        driver.wait(timeout=30)
    assert not any((out / "t" / "jobs" / "ball").glob("*/done.json"))
    again = run_sweep(path, out, SweepOptions(workers=1, until="drips", resume=True))
    assert again.ok and again.done == 3 and again.resumed == 0


def test_a_worker_ignores_ctrl_c_and_dies_with_its_driver(tmp_path, wait_for):
    """The worker side on its own: a process that ran the initializer dies when its parent does."""
    script = tmp_path / "driver.py"
    flag = tmp_path / "child.pid"
    script.write_text(
        "import multiprocessing, os, sys, time\n"
        "from icefarm.farm.local import _worker_init\n"
        "def child(flag, driver):\n"
        "    _worker_init(driver)\n"
        "    open(flag, 'w').write(str(os.getpid()))\n"
        "    time.sleep(600)\n"
        "if __name__ == '__main__':\n"
        "    ctx = multiprocessing.get_context('spawn')\n"
        "    p = ctx.Process(target=child, args=(sys.argv[1], os.getpid()))\n"
        "    p.start()\n"
        "    time.sleep(600)\n")
    driver = subprocess.Popen([sys.executable, str(script), str(flag)], start_new_session=True)
    try:
        pid = int(wait_for(lambda: flag.is_file() and flag.read_text(), "the worker to start"))
        os.kill(pid, signal.SIGINT)  # ignored: Ctrl-C is the driver's
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
        wait_for(lambda: not alive(pid), "the orphaned worker to end", timeout=30)
        # multiprocessing's resource tracker ends too, once it reads the driver's pipe closed
        wait_for(lambda: not session_processes(driver.pid), "the driver's session to empty", timeout=30)
    finally:
        for pid in session_processes(driver.pid):
            os.kill(pid, signal.SIGKILL)


# --------------------------------------------------------------------------- the stage cache

def job(tmp_path: Path, ball: Path, **values) -> JobSpec:
    p = params.resolve({"water.rays": 300, "drips.count": 4, "proxy.mode": "never", **values})
    return JobSpec("ball", str(ball), 0.3, p, seed=3)


def test_a_damaged_cache_entry_is_recomputed_with_a_warning(tmp_path, ball):
    cache = tmp_path / "cache"
    first = run_job(job(tmp_path, ball), tmp_path / "a", cache, until=Stage.TRAJECTORIES)
    assert first.status == "done" and first.reused == ()
    entries = sorted(cache.glob("*/*.npz"))
    assert {e.parent.name for e in entries} == {"refine", "water", "drips", "trajectories"}
    assert all(e.read_bytes().startswith(b"icefarm-cache 2 ") for e in entries)
    damaged = next(e for e in entries if e.parent.name == "drips")
    data = bytearray(damaged.read_bytes())
    data[-20] ^= 0xFF  # one flipped byte deep in the entry: it may still decode
    damaged.write_bytes(bytes(data))
    with pytest.warns(CacheWarning, match="drips.*damaged.*recomputed"):
        second = run_job(job(tmp_path, ball, **{"trajectories.curve_angle": 20}), tmp_path / "b", cache,
                         until=Stage.TRAJECTORIES)
    assert second.status == "done" and set(second.reused) == {"refine", "water"}
    assert (tmp_path / "a" / "drips.json").read_text() == (tmp_path / "b" / "drips.json").read_text()
    assert "damaged" in json.loads((tmp_path / "b" / "done.json").read_text())["cache_warnings"][0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the entry was written again, intact
        third = run_job(job(tmp_path, ball), tmp_path / "c", cache, until=Stage.TRAJECTORIES)
    assert set(third.reused) == {"refine", "water", "drips", "trajectories"}


def test_cache_entries_of_other_code_are_not_read(tmp_path, ball, monkeypatch):
    cache = tmp_path / "cache"
    assert run_job(job(tmp_path, ball), tmp_path / "a", cache, until=Stage.DRIPS).status == "done"
    code = StageCache.code_version()
    assert all(f".{code}." in e.name for e in cache.glob("*/*.npz"))
    monkeypatch.setattr(StageCache, "_code", "0123456789ab")  # the code changed
    again = run_job(job(tmp_path, ball), tmp_path / "b", cache, until=Stage.DRIPS)
    assert again.status == "done" and again.reused == ()


def test_a_sweep_caches_only_what_another_job_can_reuse(tmp_path, write_manifest):
    path = write_manifest(grid={"trajectories.curve_angle": [1, 5, 9]})
    summary = run_sweep(path, tmp_path / "out", SweepOptions(workers=1, until="trajectories"))
    assert summary.ok and summary.done == 3
    cache = tmp_path / "out" / "t" / "cache"
    # the trajectories and every cached step downstream of them are each job's own
    assert set(json.loads((cache / "policy.json").read_text())["private"]) == {"trajectories", "landing", "surface"}
    assert list((cache / "water").glob("*.npz")) and list((cache / "drips").glob("*.npz"))
    assert not list(cache.glob("trajectories/*.npz")), "no other job reads a job's own trajectories"
    assert all(set(r.reused) == {"refine", "water", "drips"} for r in summary.jobs[1:])


# --------------------------------------------------------------------------- resume checks

def test_resume_redoes_jobs_whose_artifacts_or_done_json_were_damaged(tmp_path, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3, 4, 5]})
    out = tmp_path / "out"
    first = run_sweep(path, out, SweepOptions(workers=1, until="drips"))
    assert first.done == 4
    deleted, truncated, flipped, intact = (r.job_dir for r in first.jobs)
    done = json.loads((intact / "done.json").read_text())
    assert {"params.yaml", "water.ply", "drips.json", "timings.json"} <= set(done["artifacts"])
    assert all(e["size"] > 0 and len(e["sha256"]) == 64 for e in done["artifacts"].values())
    (deleted / "drips.json").unlink()
    text = (truncated / "done.json").read_text()
    (truncated / "done.json").write_text(text[:len(text) // 2])
    data = bytearray((flipped / "water.ply").read_bytes())
    data[-5] ^= 0x01  # same size, other bytes
    (flipped / "water.ply").write_bytes(bytes(data))
    notes: list[str] = []
    plan = run_sweep(path, out, SweepOptions(until="drips", resume=True, dry_run=True), note=notes.append)
    assert plan.resumed == 1
    again = run_sweep(path, out, SweepOptions(workers=1, until="drips", resume=True), note=notes.append)
    assert again.ok and again.resumed == 1
    assert {r.job_dir for r in again.jobs if not r.resumed} == {deleted, truncated, flipped}
    text = "\n".join(notes)
    assert "drips.json is missing" in text and "done.json is damaged" in text and "water.ply changed" in text
    assert all((d / "drips.json").is_file() for d in (deleted, truncated, flipped))


def test_resume_on_an_edited_manifest_names_the_stale_job_folders(tmp_path, write_manifest):
    out = tmp_path / "out"
    first = run_sweep(write_manifest(grid={"drips.count": [2, 3]}), out, SweepOptions(workers=1, until="drips"))
    assert first.done == 2
    edited = write_manifest(grid={"drips.count": [3, 5]})  # 2 is gone, 5 is new
    notes: list[str] = []
    again = run_sweep(edited, out, SweepOptions(workers=1, until="drips", resume=True), note=notes.append)
    assert again.ok and again.resumed == 1
    stale = first.jobs[0].job_dir
    assert again.stale == (stale,)
    assert any("stale" in n and str(stale.relative_to(out / "t")) in n for n in notes)
    from icefarm.farm.commands import format_summary

    assert "1 stale job folder(s)" in format_summary(again)


# --------------------------------------------------------------------------- file modes

@pytest.mark.parametrize("umask,mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_atomically_written_files_follow_the_umask(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        atomic_write(tmp_path / "f.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == mode


def test_a_sweep_folder_is_readable_by_the_group_under_umask_002(tmp_path, write_manifest):
    old = os.umask(0o002)
    try:
        summary = run_sweep(write_manifest(grid={"drips.count": [2]}), tmp_path / "out",
                            SweepOptions(workers=1, until="water"))
    finally:
        os.umask(old)
    root = tmp_path / "out" / "t"
    files = [root / "jobs.csv", root / "manifest.resolved.yaml", summary.jobs[0].job_dir / "done.json",
             summary.jobs[0].job_dir / "water.ply", *root.glob("cache/*/*.npz")]
    assert all(f.stat().st_mode & 0o777 == 0o664 for f in files), {str(f): oct(f.stat().st_mode) for f in files}
