"""The numpy MLP's first layer for wide, mostly-zero inputs (Taxi's one-hot observation: 5 of 519 inputs set), as
row lookups and scatter-adds instead of dense matrix products.

For input x (with its ones column, the bias input) and the augmented first-layer matrix a1 = [w1; b1], the
pre-activation of a row is the sum, over the row's nonzero inputs c, of x[c] * a1[c]: a gather of a few rows of
a1 instead of a product with all of them. The gradient of a1 is nonzero only in those rows: each row's
d_pre, scaled by x[c], added into a1's row c (sorted, then summed in order with np.add.reduceat). Summation runs
over the inputs in ascending column order (bias last) and over the minibatch's rows in order, so a trial's
numbers depend only on its own inputs, never on the batch beside it; they differ from the dense product's (a
BLAS kernel's own order) in the last bits. tests/core/test_parts.py checks both against torch autograd.

Which path a network takes is fixed by its shape (`takes_rows`), never by the data in one call, so a trial
computes the same way alone or batched, in the runner and in the live learner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A first layer with at least this many inputs is taken as row lookups (Taxi's 519); the maze's 2 or 8 inputs
# are dense (a product with a handful of rows costs less than the bookkeeping).
ROWS_MIN_INPUTS = 64


def takes_rows(a1: np.ndarray) -> bool:
    """Whether a first layer a1 [n, in + 1, hidden] is evaluated by row lookups."""
    return a1.shape[1] - 1 >= ROWS_MIN_INPUTS


@dataclass
class NonzeroInputs:
    """The nonzero entries of x1 [n, N, D] (rows of the flattened [n * N, D]), in row-major order: entry e is
    x1's row `row[e]` (of trial `trial[e]`), column `col[e]`, value `val[e]`; `slots[k]` are the entries that
    are the k-th nonzero of their row (every row has one: its bias input), `ones` whether all values are 1."""

    n: int
    N: int
    row: np.ndarray
    trial: np.ndarray
    col: np.ndarray
    val: np.ndarray
    slots: list[np.ndarray]
    ones: bool

    @classmethod
    def of(cls, x1: np.ndarray) -> NonzeroInputs:
        n, N, D = x1.shape
        flat = x1.reshape(n * N, D)
        row, col = np.nonzero(flat != 0)  # (a boolean scan: about twice as fast as one over the floats)
        val = flat[row, col]
        counts = np.bincount(row, minlength=n * N)
        starts = np.cumsum(counts) - counts  # each row's first entry
        slots = [starts[counts > k] + k for k in range(int(counts.max(initial=0)))]
        return cls(n, N, row, row // N, col, val, slots, bool(np.all(val == 1)))


def rows_forward(a1: np.ndarray, nz: NonzeroInputs) -> np.ndarray:
    """x1 @ a1 for x1 given by its nonzero entries: [n, N, hidden], float32. Row by row, the terms are added in
    column order (the first term of each row starts it)."""
    hidden = a1.shape[2]
    pre = np.empty((nz.n * nz.N, hidden), np.float32)
    for k, e in enumerate(nz.slots):
        term = a1[nz.trial[e], nz.col[e]]
        if not nz.ones:
            term *= nz.val[e, None]
        if k == 0:  # (every row has a first entry: the rows of `e` are all rows, in order)
            pre[nz.row[e]] = term
        else:
            pre[nz.row[e]] += term
    return pre.reshape(nz.n, nz.N, hidden)


def rows_backward(d_pre: np.ndarray, nz: NonzeroInputs, in_plus_one: int) -> tuple[np.ndarray, np.ndarray]:
    """The gradient of a1 from d_pre [n, N, hidden]: (keys, sums), the rows of a1 it touches as flat keys
    trial * (in + 1) + column (ascending, distinct), and each one's gradient [len(keys), hidden]. Every other row
    of a1 has gradient zero."""
    contrib = d_pre.reshape(nz.n * nz.N, -1)[nz.row]
    if not nz.ones:
        contrib *= nz.val[:, None]
    key = nz.trial * in_plus_one + nz.col
    order = np.argsort(key, kind="stable")  # (stable: each key's terms stay in minibatch order)
    key = key[order]
    starts = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1])))
    return key[starts], np.add.reduceat(contrib[order], starts, axis=0)
