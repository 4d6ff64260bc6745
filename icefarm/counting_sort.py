"""A stable counting sort of integer keys from a small range, compiled (`geometry.stable_order`)."""

from __future__ import annotations

import numpy as np

from .compiled import compiled


@compiled()
def counting_order(keys: np.ndarray, low: int, span: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` for integer ``keys`` (n,) in ``low`` ..
    ``low + span - 1``: each key's count, their running sums, then each position dealt to
    its key's next slot. Linear in ``n + span``."""
    start = np.zeros(span + 1, dtype=np.int64)
    for i in range(len(keys)):
        start[keys[i] - low + 1] += 1
    for k in range(span):
        start[k + 1] += start[k]
    order = np.empty(len(keys), dtype=np.int64)
    for i in range(len(keys)):
        k = keys[i] - low
        order[start[k]] = i
        start[k] += 1
    return order
