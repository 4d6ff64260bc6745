"""Benchmarks and Table 2: medians over repeated runs, never run as tests.

`timings` (the stages, a job's render, growth frames: medians over repeated runs),
`table2_rows` (Table 2's rows: the paper's numbers and the objects that stand in for the
paper's), `table2` and `table2_write` (Table 2 measured and written), `storm_figures`
(the figures a storm is judged by, on a finished job) and `commands` (``icefarm bench``, the command line's
face of the package, as `farm.commands` is the sweep's).

The package's face: the names the rest of icefarm imports from it, listed in `__all__` and
loaded on first use (`lazy_loader`, as scikit-image does), so that importing one module of
the package imports no other.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "commands": ["bench"],
})
