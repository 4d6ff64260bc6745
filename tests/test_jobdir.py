"""One reading of a job folder's records, shared by the sweep, report, sheets and CLI."""

from icefarm.jobdir import error_line, total_seconds


def test_the_line_that_stands_for_a_failure_names_the_exception():
    assert error_line("\n  ValueError: bad mesh\n  at line 3\n") == "ValueError: bad mesh"
    assert error_line(None) == "-" and error_line("  \n", "unknown error") == "unknown error"


def test_a_jobs_total_seconds_sums_its_steps_and_nothing_else():
    assert total_seconds({"water": 0.5, "render": 2.0, "cached": True, "note": "x"}) == 2.5
    assert total_seconds({}) is None and total_seconds(None) is None and total_seconds([1, 2]) is None
