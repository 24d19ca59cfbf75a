"""The numpy MLP's arithmetic, written out by hand (see networks.py): torch's initialisation without torch, the
parameters as views of one flat row per trial, the batched forward pass and the exact gradient, dense or, for a
wide first layer of mostly-zero inputs, by row lookups.

Row lookups (Taxi's one-hot observation: 5 of 519 inputs set): for input x (with its ones column, the bias input)
and the augmented first-layer matrix a1 = [w1; b1], the pre-activation of a row is the sum, over the row's nonzero
inputs c, of x[c] * a1[c]: a gather of a few rows of a1 instead of a product with all of them. The gradient of a1
is nonzero only in those rows: each row's d_pre, scaled by x[c], added into a1's row c (sorted, then summed in
order with np.add.reduceat). Summation runs over the inputs in ascending column order (bias last) and over the
minibatch's rows in order, so a trial's numbers depend only on its own inputs, never on the batch beside it; they
differ from the dense product's (a BLAS kernel's own order) in the last bits. tests/core/test_parts.py checks both
against torch autograd.

Which path a network takes is fixed by its shape (`takes_rows`), never by the data in one call, so a trial
computes the same way alone or batched, in the runner and in the live learner.
"""

from __future__ import annotations

import math
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


PARAM_NAMES = ("w1", "b1", "w2", "b2")


def torch_uniform(seed: int, n: int) -> np.ndarray:
    """The first n numbers of `torch.rand(n, generator=torch.Generator().manual_seed(seed))` (float32), without
    torch: its CPU generator is a 32-bit Mersenne Twister seeded with the seed's low 32 bits, the same as
    numpy's legacy seeding, and a float is the low 24 bits of one draw over 2**24. Importing torch costs a
    service about 1.3 s of CPU at start; tests/core/test_parts.py checks this against torch."""
    legacy = np.random.RandomState(int(seed) % (2**63) & 0xFFFFFFFF)
    raw = legacy.randint(0, 2**32, size=n, dtype=np.uint32)  # (the full 32-bit range: one raw draw each)
    return (raw & 0xFFFFFF).astype(np.float32) * np.float32(2.0**-24)


def init_mlp(in_dim: int, hidden: int, out_dim: int, seed: int) -> dict[str, np.ndarray]:
    """PyTorch's nn.Linear default initialisation (uniform +-1/sqrt(fan_in)) for one trial, as float32 arrays
    equal to what torch's generator gives (the draws in the order torch makes them)."""
    shapes = param_shapes(in_dim, hidden, out_dim)
    draws = torch_uniform(seed, sum(a * b for a, b in shapes.values()))
    out, at = {}, 0
    for name in PARAM_NAMES:
        size = shapes[name][0] * shapes[name][1]
        bound = np.float32(1.0 / math.sqrt(in_dim if name in ("w1", "b1") else hidden))  # 1/sqrt(fan_in)
        out[name] = (draws[at : at + size].reshape(shapes[name]) * np.float32(2) - np.float32(1)) * bound
        at += size
    return out


def param_shapes(in_dim: int, hidden: int, out_dim: int) -> dict[str, tuple[int, int]]:
    return {"w1": (in_dim, hidden), "b1": (1, hidden), "w2": (hidden, out_dim), "b2": (1, out_dim)}


def views(flat: np.ndarray, shapes: dict[str, tuple[int, int]], names: bool = False) -> dict[str, np.ndarray]:
    """Views into the rows of a flat [n, P] parameter array: the augmented first-layer matrix
    a1 = [w1; b1] ([n, in + 1, hidden]), w2 and b2 (what `mlp_forward` and `mlp_backward` use), and
    with names=True also w1 and b1."""
    n = flat.shape[0]
    (i, h), (_, k) = shapes["w1"], shapes["w2"]
    o = (i + 1) * h
    out = {
        "a1": flat[:, :o].reshape(n, i + 1, h),
        "w2": flat[:, o : o + h * k].reshape(n, h, k),
        "b2": flat[:, o + h * k :].reshape(n, 1, k),
    }
    if names:
        out["w1"] = flat[:, : i * h].reshape(n, i, h)
        out["b1"] = flat[:, i * h : o].reshape(n, 1, h)
    return out


_CONSTANTS: dict[tuple, np.ndarray] = {}


def _constant(kind: str, *shape: int) -> np.ndarray:
    """A read-only np.ones (float32) or np.arange of this shape, or ("offsets", n, A) the flat positions of n
    rows of A values, made once (they were made at every step)."""
    got = _CONSTANTS.get((kind, shape))
    if got is None:
        got = (
            np.ones(shape, np.float32)
            if kind == "ones"
            else np.arange(shape[0]) * shape[1]
            if kind == "offsets"
            else np.arange(*shape)
        )
        got.flags.writeable = False
        _CONSTANTS[(kind, shape)] = got
    return got


def with_ones(x: np.ndarray) -> np.ndarray:
    """x [n, N, k] with a column of ones appended (the bias input): [n, N, k + 1]."""
    out = np.empty((*x.shape[:-1], x.shape[-1] + 1), np.float32)
    out[..., :-1] = x
    out[..., -1] = 1.0
    return out


def mlp_forward(
    p: dict[str, np.ndarray], x: np.ndarray, x1: np.ndarray | None = None, nz: NonzeroInputs | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(hidden activations, outputs) for x: [n, N, in] -> [n, N, hidden], [n, N, out]. x1: `with_ones(x)`
    if the caller has it already; nz: its nonzero entries, for a wide first layer (`takes_rows`)."""
    x1 = with_ones(x) if x1 is None else x1
    if takes_rows(p["a1"]):
        h = rows_forward(p["a1"], NonzeroInputs.of(x1) if nz is None else nz)
    else:
        h = x1 @ p["a1"]
    np.tanh(h, out=h)
    out = h @ p["w2"]
    out += p["b2"]
    return h, out


def row_max(q: np.ndarray) -> np.ndarray:
    """max over the last (small) axis, column by column: much faster than q.max(-1) for a few actions."""
    m = q[..., 0].copy()
    for a in range(1, q.shape[-1]):
        np.maximum(m, q[..., a], out=m)
    return m


def mlp_backward(
    p: dict[str, np.ndarray],
    x: np.ndarray,
    h: np.ndarray,
    d_out: np.ndarray,
    x1: np.ndarray | None = None,
    nz: NonzeroInputs | None = None,
) -> np.ndarray:
    """`mlp_backward_rows`' gradient alone."""
    return mlp_backward_rows(p, x, h, d_out, x1, nz)[0]


def mlp_backward_rows(
    p: dict[str, np.ndarray],
    x: np.ndarray,
    h: np.ndarray,
    d_out: np.ndarray,
    x1: np.ndarray | None = None,
    nz: NonzeroInputs | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(grad, touched): gradient of sum(d_out * out) with respect to each trial's weights, flat [n, P] (w1, b1, w2, b2).

    h is `mlp_forward`'s first output (x1: `with_ones(x)` if the caller has it). Bias gradients are sums over
    the N rows, written as products (with the ones column of the augmented input, or a row of ones) so that
    every reduction is a per-trial matrix product. A wide first layer's gradient is a scatter-add of d_pre into
    the rows of its nonzero inputs (`rows_backward`; nz: `NonzeroInputs.of(x1)` where the caller has it):
    then `touched` are the first-layer rows it touched (flat keys trial * (in + 1) + input; every other row's
    gradient is zero), else None."""
    n = x.shape[0]
    g_w2, g_b2, d_pre = _backward_top(p, h, d_out)
    x1 = with_ones(x) if x1 is None else x1
    if not takes_rows(p["a1"]):
        g1 = x1.transpose(0, 2, 1) @ d_pre  # [n, in + 1, hidden] = (w1; b1)
        return np.concatenate([g1.reshape(n, -1), g_w2.reshape(n, -1), g_b2.reshape(n, -1)], axis=1), None
    in1, hidden = p["a1"].shape[1:]
    tail, keys, sums = _sparse_first_layer(d_pre, g_w2, g_b2, x1, nz, in1)
    grad = np.zeros((n, in1 * hidden + tail.shape[1]), np.float32)
    grad[:, : in1 * hidden].reshape(n, in1, hidden)[keys // in1, keys % in1] = sums  # (a view: splits one axis)
    grad[:, in1 * hidden :] = tail
    return grad, keys


def mlp_backward_sparse(
    p: dict[str, np.ndarray], h: np.ndarray, d_out: np.ndarray, x1: np.ndarray, nz: NonzeroInputs
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`mlp_backward_rows` of a first layer that takes rows, without the dense gradient: (tail, keys, sums), the
    gradient of w2 and b2 [n, hidden * out + out], the touched first-layer rows (flat keys trial * (in + 1) + input,
    ascending) and their gradients [len(keys), hidden] (every other first-layer row's gradient is zero)."""
    g_w2, g_b2, d_pre = _backward_top(p, h, d_out)
    return _sparse_first_layer(d_pre, g_w2, g_b2, x1, nz, p["a1"].shape[1])


def _backward_top(p: dict[str, np.ndarray], h: np.ndarray, d_out: np.ndarray):
    """(g_w2, g_b2, d_pre): the output layer's gradient and d loss / d pre-activation."""
    n, N = h.shape[:2]
    g_w2 = h.transpose(0, 2, 1) @ d_out  # [n, hidden, out]
    g_b2 = _constant("ones", n, 1, N) @ d_out  # [n, 1, out]
    d_pre = d_out @ p["w2"].transpose(0, 2, 1)  # [n, N, hidden]
    slope = h * h
    np.subtract(np.float32(1), slope, out=slope)  # tanh' = 1 - tanh^2
    d_pre *= slope
    return g_w2, g_b2, d_pre


def _sparse_first_layer(d_pre, g_w2, g_b2, x1, nz, in1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(d_pre)
    keys, sums = rows_backward(d_pre, NonzeroInputs.of(x1) if nz is None else nz, in1)
    return np.concatenate([g_w2.reshape(n, -1), g_b2.reshape(n, -1)], axis=1), keys, sums
