"""A job's steps as one declared graph and the one runner that runs it.

`graph` declares each step once (`STEPS`); `work` holds what each computes, `figures` what
each writes and reports; `runner` runs the graph for a job, a sweep worker, the benchmarks,
Table 2, growth frames and the tests. Loaded on first use (`lazy_loader`).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "figures": ["finite", "finite_list", "ice_mesh", "storm_figures"],
    "graph": ["STEPS", "STEP_NAMES", "SURFACE_STEP", "Input", "Step", "When", "ancestors", "cached_steps",
              "overridable", "read_values", "runs", "share_digest", "step", "step_keys"],
    "records": ["STAGE_ORDER", "JobInputs", "Stage", "StageResults", "stage_rng", "stops"],
    "runner": ["StepRunner", "run_graph", "run_stages", "run_step"],
    "work": ["WRAP_REACH", "IceFigures", "build_surface", "sole"],
})
