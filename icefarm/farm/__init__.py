"""The farm: manifests, sweeps of jobs over their points, the workers that run them (a local
process pool or Dask), and the commands ``icefarm validate``, ``icefarm sweep`` and
``icefarm bench farm`` (`commands`).

The package's face: the names the rest of icefarm imports from it, listed in `__all__` and
loaded on first use (`lazy_loader`, as scikit-image does), so that importing one module of
the package imports no other.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "commands": ["bench_farm", "make_sweep_command", "validate"],
    "sweep": ["SweepOptions", "run_sweep"],
})
