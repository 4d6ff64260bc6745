"""icefarm: procedural icicles and glaze ice on any mesh, rendered in batch.

The Python API (`icefarm.api`, docs/api.md): `grow` ice on a mesh, get an `Ice` back,
`write` it as a job folder or `render` it. Its names are loaded on first use
(`lazy_loader`, as scikit-image does), so ``import icefarm`` (the command line's first
import) stays cheap; ``__init__.pyi`` declares them for type checkers.
"""

from importlib.metadata import PackageNotFoundError, version

import lazy_loader as _lazy

try:
    __version__ = version("icefarm")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0"

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submod_attrs={
    "api": ["Ice", "Icicles", "grow", "render", "write"],
})
