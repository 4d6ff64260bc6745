# The names `icefarm/__init__.py` loads on first use, for type checkers (PEP 561, py.typed).
from .api import Ice as Ice, Icicles as Icicles, grow as grow, render as render, write as write

__version__: str
__all__ = ["Ice", "Icicles", "grow", "render", "write"]
