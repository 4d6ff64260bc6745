"""One job: its steps as one declared graph, the one runner that runs it, and the job around it.

`graph` declares each step once (`STEPS`); `work` holds what each computes, `figures` what
each writes and reports; `runner` runs the graph for a job, a sweep worker, the benchmarks,
Table 2, growth frames and the tests. `pipeline` runs a whole job into its folder
(`run_job`: the graph through `cache` and `codec`, then `render` and the growth `frames`).
The folder's contract (`icefarm.jobdir`, `icefarm.artifacts`) lies below this package:
every package reads job folders. Loaded on first use (`lazy_loader`).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "figures": ["finite", "finite_list", "ice_mesh", "storm_figures"],
    "graph": ["STEPS", "STEP_NAMES", "SURFACE_STEP", "Input", "Step", "When", "ancestors", "beside_render",
              "cached_steps", "overridable", "read_values", "runs", "share_digest", "step", "step_keys"],
    "records": ["STAGE_ORDER", "JobInputs", "Stage", "StageResults", "stage_rng", "stops"],
    "runner": ["StepRunner", "run_graph", "run_stages", "run_step"],
    "stats": ["JobStats"],
    "work": ["WRAP_REACH", "IceFigures", "build_surface", "sole"],
})
