"""Benchmarks and Table 2: medians over repeated runs, never run as tests.

`timings` (the stages, a job's render, growth frames: medians over repeated runs),
`table2_rows` (Table 2's rows: the paper's numbers and the objects that stand in for the
paper's), `table2` and `table2_write` (Table 2 measured and written), `storm_figures`
(issue 23's figures of a finished job) and `commands` (``icefarm bench``, the command line's
face of the package, as `farm.commands` is the sweep's).
"""
