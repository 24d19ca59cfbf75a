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

_CODE_ROWS: dict[tuple, tuple] = {}  # (n, N, K) -> the row indices of codes of that shape (`NonzeroInputs.of_codes`)
_ONES: dict[int, np.ndarray] = {}


def _ones(size: int) -> np.ndarray:
    got = _ONES.get(size)
    if got is None:
        got = _ONES[size] = np.ones(size, np.float32)
        got.flags.writeable = False
    return got


class HotCodes:
    """Observations of `dim` inputs that are 0 or 1 with exactly `k` ones (Taxi's: one-hot groups), kept as codes:
    the k columns set, ascending, then `dim` (the column of the bias input, always 1), as float32 (exact). A network
    that takes rows computes from the codes exactly what it computes from the dense input (the same terms in the
    same order: `NonzeroInputs.of_codes`), so an agent may store codes (k + 1 numbers instead of dim + 1)."""

    def __init__(self, dim: int, k: int):
        self.dim, self.k, self.width = int(dim), int(k), int(k) + 1

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """obs [..., dim] -> codes [..., k + 1]; a ValueError if an observation is not k ones and zeros."""
        flat = np.asarray(obs).reshape(-1, self.dim)
        m = len(flat)
        row, col = np.nonzero(flat)
        if len(row) != m * self.k or np.any(np.bincount(row, minlength=m) != self.k) or np.any(flat[row, col] != 1):
            raise ValueError(f"observations are not {self.k} ones among {self.dim} zeros")
        out = np.empty((m, self.width), np.float32)
        out[:, : self.k] = col.reshape(m, self.k)
        out[:, self.k] = self.dim
        return out.reshape(*np.shape(obs)[:-1], self.width)


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
    every_row: bool = False  # every row has each slot (codes): slot k's entries are rows 0..n*N-1 in order

    @classmethod
    def of_codes(cls, codes: np.ndarray) -> NonzeroInputs:
        """The same for an input given by its codes (`HotCodes`: [n, N, K], each row's K nonzero columns, all
        ones, ascending, the bias input's last): no scan, the entries are the codes themselves."""
        n, N, K = codes.shape
        got = _CODE_ROWS.get((n, N, K))
        if got is None:
            row = np.repeat(np.arange(n * N), K)
            got = _CODE_ROWS[(n, N, K)] = (row, row // N, [np.arange(n * N) * K + k for k in range(K)])
        row, trial, slots = got
        return cls(n, N, row, trial, codes.reshape(-1).astype(np.intp), _ones(n * N * K), slots, True, True)

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
    if nz.every_row:  # (codes: the same additions, without scattering into rows)
        col, trial = nz.col.reshape(nz.n * nz.N, -1), nz.trial[nz.slots[0]]
        pre = a1[trial, col[:, 0]]
        for k in range(1, col.shape[1]):
            pre += a1[trial, col[:, k]]
        return pre.reshape(nz.n, nz.N, hidden)
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
