"""The one YAML reader of numbers for ``--set`` values, manifests, parameter files and configs.

PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent: ``5e-2`` and
``1e3`` are read as text and a parameter then refuses them as out of its domain. `NumberLoader`
is `yaml.SafeLoader` with the YAML 1.2 float pattern, so every way of writing a number that a
user types reads as one.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

__all__ = ["NumberLoader", "load_yaml"]

FLOAT_TAG = "tag:yaml.org,2002:float"
# YAML 1.1's float pattern with the exponent's sign optional and a dotless mantissa allowed
# before an exponent (``5e-2``, ``1E3``); sexagesimal, inf and nan as YAML 1.1 has them.
FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


class NumberLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that reads ``5e-2`` and ``1e3`` as floats (see the module's notes)."""


def _resolvers() -> dict[str, list]:
    # SafeLoader's resolvers with its float pattern replaced where it was: first for the
    # characters a number starts with (the int pattern never matches an exponent).
    out = {ch: [(tag, rx) for tag, rx in pairs if tag != FLOAT_TAG]
           for ch, pairs in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    for ch in "-+0123456789.":
        out.setdefault(ch, []).insert(0, (FLOAT_TAG, FLOAT))
    return out


NumberLoader.yaml_implicit_resolvers = _resolvers()


def load_yaml(text: str | bytes) -> Any:
    """The data of the YAML document ``text``, read safely with `NumberLoader`.

    Raises
    ------
    yaml.YAMLError
        ``text`` is not valid YAML.
    """
    return yaml.load(text, Loader=NumberLoader)
