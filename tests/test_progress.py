"""A job says what it is doing: a live line on a terminal, plain lines in a log."""

from __future__ import annotations

import io
import time

import pytest

from icefarm.progress import ProgressMode, step_progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_mode_follows_the_stream():
    assert ProgressMode.for_stream(_Tty()) is ProgressMode.BAR
    assert ProgressMode.for_stream(io.StringIO()) is ProgressMode.LINES


def test_plain_lines_name_each_step_its_parts_and_its_time():
    out = io.StringIO()
    progress = step_progress(ProgressMode.LINES, out)
    with progress.step("surface"):
        progress.note("meshing 12 blocks")
    with pytest.raises(RuntimeError), progress.step("render"):
        raise RuntimeError("boom")
    lines = out.getvalue().splitlines()
    assert lines[0] == "surface ..." and lines[1] == "  surface: meshing 12 blocks"
    assert lines[2].startswith("surface done in ") and lines[2].endswith(" s")
    assert lines[4].startswith("render failed after ")
    assert "\r" not in out.getvalue()


def test_the_live_line_ticks_while_a_step_runs_and_goes_when_it_ends():
    out = _Tty()
    progress = step_progress(ProgressMode.BAR, out)
    progress.REFRESH_S = 0.1  # five times a terminal's rate: a short wait
    with progress.step("surface"):
        progress.note("glaze coat")
        time.sleep(3 * progress.REFRESH_S)
    text = out.getvalue()
    assert text.count("\r\033[Ksurface") >= 2 and "glaze coat" in text  # refreshed, with the part it is on
    assert text.endswith("\r\033[K")  # cleared: the run's summary follows on a clean line


def test_off_writes_nothing():
    out = io.StringIO()
    progress = step_progress(ProgressMode.OFF, out)
    with progress.step("surface"):
        progress.note("x")
    assert out.getvalue() == ""


def test_a_job_run_from_a_log_prints_each_step_and_the_surface_parts(tmp_path):
    from click.testing import CliRunner

    from icefarm.cli import main

    result = CliRunner().invoke(main, ["run", "generator:roof", "--size-m", "0.4", "--no-render",
                                       "--set", "storm.mode=relative", "--set", "drips.count=4",  # quick: four icicles
                                       "--set", "surface.voxel_size=0.006", "--set", "glaze.voxel_size=0.024",
                                       "-o", str(tmp_path / "roof")])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    for step in ("prepare", "water", "drips", "trajectories", "surface", "measure"):
        assert f"{step} ..." in lines and any(line.startswith(f"{step} done in ") for line in lines)
    parts = [line for line in lines if line.startswith("  surface: ")]
    assert [p.split(": ")[1].split(" ")[0] for p in parts] == ["glaze", "icicle", "meshing", "ripples", "clean-up"]
    assert "\r" not in result.stdout


def test_sweep_lines_say_what_runs_and_the_time_left():
    from icefarm.farm.commands import LineProgress, time_left
    from icefarm.farm.sweep import JobRecord
    from icefarm.jobdir import JobState

    assert time_left(30.0, 2, 4) == "about 60 s left" and time_left(60.0, 2, 4) == "about 2 min left"
    assert time_left(600.0, 1, 8) == "about 80 min left" and time_left(600.0, 1, 9) == "about 1.5 h left"
    assert time_left(0.0, 0, 3) == "" and time_left(5.0, 3, 0) == ""
    lines = []
    progress = LineProgress(lines.append)
    progress.start(5, 1, workers=2)  # one already done: resumed
    record = JobRecord.__new__(JobRecord)
    for name, value in (("object_id", "bunny"), ("job_id", "j1"), ("values", ()), ("status", JobState.DONE),
                        ("seconds", 3.0), ("reused", ()), ("attempts", 1), ("error", None)):
        object.__setattr__(record, name, value)
    progress.update(record)
    assert lines[0].startswith("1 of 5 jobs already done")
    assert lines[1].startswith("[2/5, 2 running, about ") and lines[1].split("] ")[0].endswith(" left")
    for _ in range(3):
        progress.update(record)
    assert lines[-1].startswith("[5/5] ")  # nothing left: neither running nor time
