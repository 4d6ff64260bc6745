"""Sweeps through the real pipeline on a local process pool: layout, reuse, resume, failures,
a worker killed mid-job. Stage-only jobs (until trajectories) on a tiny icosphere."""

import csv
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from hooks.sitecustomize import pause_env

from icefarm.errors import InputError
from icefarm.farm.commands import sweep as sweep_command, validate as validate_command
from icefarm.farm.manifest import load_manifest
from icefarm.farm.plan import plan_jobs
from icefarm.farm.sweep import SweepOptions, run_sweep
from icefarm.jobdir import JobState

pytestmark = pytest.mark.slow  # real processes, clusters and renders: `pytest -m "not slow"` skips them

def test_sweep_layout_and_stage_reuse(tmp_path, write_manifest):
    path = write_manifest(grid={"trajectories.curve_angle": [1, 5], "surface.ripple_amplitude": [0.0, 0.001]})
    out = tmp_path / "out"
    summary = run_sweep(path, out, SweepOptions(workers=2, until="trajectories"))
    assert summary.ok and summary.done == 4 and summary.failed == 0
    root = out / "t"
    resolved = yaml.safe_load((root / "manifest.resolved.yaml").read_text())
    assert len(resolved["jobs"]) == 4 and resolved["objects"][0]["params"]["drips"]["count"] == 4
    rows = list(csv.DictReader((root / "jobs.csv").open()))
    assert [r["status"] for r in rows] == ["done"] * 4
    assert set(rows[0]) >= {"job_id", "object", "trajectories.curve_angle", "surface.ripple_amplitude", "seconds"}
    for r in summary.jobs:
        assert r.job_dir == root / "jobs" / "ball" / r.job_id
        assert (r.job_dir / "done.json").is_file() and (r.job_dir / "trajectories.json").is_file()
    # The first job computes stages 1-3; the others wait for it and reuse what they share:
    # the same curve angle shares all three stages, the other one shares water and drips.
    first, *others = summary.jobs
    assert first.reused == ()
    assert all({"water", "drips"} <= set(r.reused) for r in others)
    assert summary.reused >= 3 + 2 + 2
    assert (root / "cache").is_dir() and not (root / ".farm").exists()


def test_existing_folder_is_refused_and_resume_redoes_exactly_the_unfinished_job(tmp_path, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3, 4]})
    out = tmp_path / "out"
    first = run_sweep(path, out, SweepOptions(workers=1, until="drips"))
    assert first.done == 3
    with pytest.raises(InputError, match="already exists: add --resume"):
        run_sweep(path, out, SweepOptions(until="drips"))
    redo = first.jobs[1].job_dir
    (redo / "done.json").unlink()
    (redo / "leftover.tmp").write_text("half-written")
    stamps = {r.job_id: (r.job_dir / "done.json").stat().st_mtime_ns for r in first.jobs if r.job_dir != redo}
    again = run_sweep(path, out, SweepOptions(workers=1, until="drips", resume=True))
    assert again.ok and again.resumed == 2
    assert [r.job_id for r in again.jobs if not r.resumed] == [first.jobs[1].job_id]
    assert (redo / "done.json").is_file() and not (redo / "leftover.tmp").exists()
    assert {j: (out / "t" / "jobs" / "ball" / j / "done.json").stat().st_mtime_ns for j in stamps} == stamps
    nothing = run_sweep(path, out, SweepOptions(until="drips", resume=True))
    assert nothing.resumed == 3 and nothing.ok
    plan = run_sweep(path, out, SweepOptions(until="drips", overwrite=True, dry_run=True))
    assert plan.dry_run and plan.resumed == 3  # a dry run deletes nothing


def test_overwrite_refuses_a_folder_that_is_not_a_sweep(tmp_path, write_manifest):
    path = write_manifest()
    (tmp_path / "out" / "t").mkdir(parents=True)
    (tmp_path / "out" / "t" / "precious.txt").write_text("keep me")
    with pytest.raises(InputError, match="does not look like an icefarm sweep folder"):
        run_sweep(path, tmp_path / "out", SweepOptions(overwrite=True, until="water"))
    assert (tmp_path / "out" / "t" / "precious.txt").exists()


def test_a_failing_job_does_not_stop_the_others(tmp_path, ball, write_manifest):
    (tmp_path / "broken.obj").write_text("v 0 0 0\nf 1 2 3\nthis is not a mesh\n")
    path = write_manifest(grid={"drips.count": [2, 3]}, objects=[{"id": "bad", "mesh": "broken.obj", "size_m": 0.3},
                                                                {"id": "ball", "mesh": ball.name, "size_m": 0.3}])
    assert CliRunner().invoke(validate_command, [str(path)]).exit_code == 0  # it exists: valid
    result = CliRunner().invoke(sweep_command, [str(path), "-o", str(tmp_path / "out"), "--workers", "2",
                                                "--until", "drips"])
    assert result.exit_code == 1, result.output
    assert "2 done, 2 failed of 4 jobs" in result.output and "FAILED bad/" in result.output
    rows = list(csv.DictReader((tmp_path / "out" / "t" / "jobs.csv").open()))
    assert {(r["object"], r["status"]) for r in rows} == {("bad", "failed"), ("ball", "done")}
    for row in rows:
        if row["object"] == "bad":
            folder = tmp_path / "out" / "t" / "jobs" / "bad" / row["job_id"]
            assert (folder / "error.json").is_file() and not (folder / "done.json").exists()
            assert row["error"]


def test_a_second_sweep_on_a_running_folder_is_refused_and_deletes_nothing(tmp_path, monkeypatch, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3]})
    out = tmp_path / "out"
    for key, value in pause_env("ball", 3).items():  # the first sweep's jobs are still running
        monkeypatch.setenv(key, value)
    first: list = []
    runner = threading.Thread(target=lambda: first.append(run_sweep(path, out, SweepOptions(workers=2, until="drips"))))
    runner.start()
    running = out / "t" / ".farm" / "running"
    deadline = time.monotonic() + 60
    while not list(running.glob("*.pid")) and time.monotonic() < deadline:
        time.sleep(0.05)
    started = {p.stem for p in running.glob("*.pid")}
    assert started, "the first sweep never started a job"
    for flags in ({"resume": True}, {"overwrite": True}):
        with pytest.raises(InputError, match=rf"another icefarm sweep \(pid {os.getpid()}\) is writing"):
            run_sweep(path, out, SweepOptions(until="drips", **flags))
    assert {p.stem for p in running.glob("*.pid")} >= started  # its markers and jobs were left alone
    runner.join()
    assert first[0].ok and first[0].done == 2
    assert run_sweep(path, out, SweepOptions(until="drips", resume=True)).resumed == 2  # the lock went with the sweep
    assert (out / ".t.lock").read_text() == ""


def test_cli_dry_run_and_bad_set(tmp_path, write_manifest):
    path = write_manifest()
    result = CliRunner().invoke(sweep_command, [str(path), "-o", str(tmp_path / "out"), "--dry-run",
                                                "--set", "drips.count=2,3,5"])
    assert result.exit_code == 0 and "3 jobs" in result.output and "drips.count=5" in result.output
    assert not (tmp_path / "out").exists()
    bad = CliRunner().invoke(sweep_command, [str(path), "--set", "drips.cuont=2"])
    assert bad.exit_code == 2 and "did you mean drips.count" in bad.output


def _kill_when_started(running: Path, job_ids: set[str], kills: int, killed: list, paused: Path,
                       timeout: float = 60) -> None:
    """Kill (SIGKILL) the worker of each new attempt of ``job_ids``, ``kills`` times in all, once
    it says (a file named by its pid in ``paused``) that it is inside its pause."""
    deadline = time.monotonic() + timeout
    seen: set[str] = set()
    while len(killed) < kills and time.monotonic() < deadline:
        for marker in running.glob("*.pid") if running.is_dir() else ():
            try:
                pids = marker.read_text().split()
            except FileNotFoundError:  # the job ended meanwhile
                continue
            if marker.stem in job_ids and pids and pids[-1] not in seen:
                seen.add(pids[-1])
                while not (paused / pids[-1]).exists() and time.monotonic() < deadline:
                    time.sleep(0.01)
                os.kill(int(pids[-1]), signal.SIGKILL)
                killed.append(marker.stem)
        time.sleep(0.02)


@pytest.mark.parametrize("kills", [1, 2])
def test_a_killed_worker_is_noticed_its_job_retried_once(tmp_path, ball, monkeypatch, kills, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3]}, objects=[{"id": "ball", "mesh": ball.name, "size_m": 0.3},
                                                                {"id": "victim", "mesh": ball.name, "size_m": 0.5}])
    victim = next(j.job_id for j in plan_jobs(load_manifest(path), render=False)[0] if j.object_id == "victim")
    paused = tmp_path / "paused"
    paused.mkdir()
    for key, value in pause_env("victim", 1.5, paused).items():  # the workers' jobs of victim pause
        monkeypatch.setenv(key, value)
    killed: list = []
    killer = threading.Thread(target=_kill_when_started,
                              args=(tmp_path / "out" / "t" / ".farm" / "running", {victim}, kills, killed, paused))
    killer.start()
    summary = run_sweep(path, tmp_path / "out", SweepOptions(workers=2, until="drips"))
    killer.join()
    assert killed == [victim] * kills
    records = {r.job_id: r for r in summary.jobs}
    assert records[victim].attempts == 2
    assert records[victim].status is (JobState.DONE if kills == 1 else JobState.FAILED)
    others = [r for r in summary.jobs if r.job_id != victim]
    assert all(r.status is JobState.DONE for r in others) and len(others) == 3
    if kills == 2:
        assert "died 2 times" in records[victim].error
        assert (records[victim].job_dir / "error.json").is_file()


def test_every_command_explains_itself():
    from icefarm.farm.commands import bench_farm

    for command, words in ((validate_command, "without running"), (sweep_command, "--resume"),
                           (bench_farm, "speed-up")):
        result = CliRunner().invoke(command, ["--help"])
        assert result.exit_code == 0 and words in result.output


def test_bench_farm_reports_medians_and_the_second_backend_s_overhead():
    from icefarm.farm.commands import BenchRun, bench_farm_report

    runs = [BenchRun(b, n, 8, wall, 0.0, 0.0) for b, n, wall in
            (("local", 1, 20.0), ("dask", 1, 23.0), ("local", 2, 10.0), ("dask", 2, 11.0),
             ("local", 1, 30.0), ("dask", 1, 21.0), ("local", 2, 12.0), ("dask", 2, 99.0),
             ("local", 1, 22.0), ("dask", 1, 22.0), ("local", 2, 11.0), ("dask", 2, 12.1))]
    lines = bench_farm_report(runs)
    assert any(line.startswith("local: speed-up 2 vs 1 worker: 2.00x") for line in lines)
    assert any(line.startswith("dask vs local, 2 workers: +10 %") for line in lines)  # 12.1 s over 11 s
    assert any(line.startswith("dask vs local, 1 worker: +0 %") for line in lines)


def test_a_job_marker_is_replaced_whole_each_attempt(tmp_path):
    # The driver and the fault tests read the running markers while workers write them: a
    # marker must never exist empty or half written, so each attempt replaces it whole.
    from icefarm.farm.task import _add_attempt

    marker = tmp_path / "running" / "job.pid"
    _add_attempt(marker)
    first = marker.stat().st_ino
    _add_attempt(marker)
    assert marker.read_text().split() == [str(os.getpid())] * 2
    assert marker.stat().st_ino != first  # a new file renamed over it, not an append in place
    assert [p.name for p in marker.parent.iterdir()] == ["job.pid"]  # no temporary file left


def test_resume_gives_a_job_folder_that_is_a_link_its_own_folder_and_leaves_the_target(tmp_path, write_manifest):
    path = write_manifest(grid={"drips.count": [2, 3]})
    out = tmp_path / "out"
    first = run_sweep(path, out, SweepOptions(workers=1, until="water"))
    linked = first.jobs[0].job_dir
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "mine.txt").write_text("keep me")
    shutil.rmtree(linked)
    linked.symlink_to(target, target_is_directory=True)
    again = run_sweep(path, out, SweepOptions(workers=1, until="water", resume=True))
    assert again.ok and again.done == 2 and again.resumed == 1
    assert linked.is_dir() and not linked.is_symlink() and (linked / "done.json").is_file()
    assert sorted(p.name for p in target.iterdir()) == ["mine.txt"]  # no error.json, nothing written there
