"""Small numpy helpers shared by the core."""

from __future__ import annotations

import numpy as np


def nz(mask: np.ndarray) -> np.ndarray:
    """Indices of the true entries of a 1-d mask (np.flatnonzero without its overhead)."""
    return mask.nonzero()[0]


class RowConstants:
    """`make(rows)`: per-trial constants picked for a set of trial rows, kept per row set. A batch asks for the
    same rows at almost every step, and picking a few small arrays by index costs more than the step's own
    arithmetic on them. The arrays returned are shared: read them, never write into them. `clear()` when the
    rows are renumbered (`select`)."""

    def __init__(self, make):
        self._make = make
        self._kept: dict[tuple, tuple] = {}

    def __call__(self, rows: np.ndarray) -> tuple:
        if not isinstance(rows, np.ndarray):
            rows = np.asarray(rows, np.int64)
        key = (rows.dtype.char, rows.tobytes())
        got = self._kept.get(key)
        if got is None:
            if len(self._kept) >= 64:
                self._kept.clear()
            got = self._kept[key] = self._make(rows)
        return got

    def clear(self) -> None:
        self._kept.clear()
