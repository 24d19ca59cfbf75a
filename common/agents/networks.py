"""Value networks (Q or H) as a component of the agent, and the fast path: a stack of independent
one-hidden-layer MLPs, one per trial, evaluated as one batched numpy computation.

The component's interface (`ValueNetworks`) is what the agent uses and all a network must provide: values of
observations for some trial rows, one optimiser step on a minibatch (observations, actions taken, targets,
weights, a loss), target syncs, row selection, state and per-trial policy weights as named numpy arrays. A
torch nn.Module can implement it (values: a forward pass; fit: loss.backward and its optimiser's step); Q and
H need not have the same shape.

The numpy MLP (`StackedMLP`): trial i's weights are W1[i], b1[i], W2[i], b2[i]. Each trial is initialised as
its own seeded torch generator would with PyTorch's nn.Linear default (so a trial gets the same weights alone
or among others, and the same as a torch model of the paper's network; `torch_uniform` draws torch's numbers
without importing torch, tested against it), then kept as float32 numpy arrays: all of a
trial's weights live in one row of a flat [B, P] array (`flat`), and `params` are views into it, so selecting
trials, an optimiser step or a target-network copy is one operation.

The arithmetic is numpy, written out by hand: forward is one batched product per layer (the first with
the augmented matrix [W1; b1] against the input with a ones column appended), and `mlp_backward` is the exact
gradient (what autograd computes for the same loss). At these sizes (a few to a hundred trials, 100
hidden units, minibatches of 32) per-call overhead dominates the arithmetic; numpy's overhead per call
is several times lower than torch's, which matters most for the last, slow trials of a batch. Every
operation is a per-trial matrix product or elementwise, never a reduction across trials, so a trial's
numbers do not depend on which or how many trials share its batch (tests/experiments/test_batching.py).

Its optimiser (`FlatRMSProp`) is torch.optim.RMSprop's update (alpha 0.99, eps 1e-8, no momentum, the same
operations in the same order: tests/core/test_agents.py checks it against torch) on the flat rows, stepping only
the trials selected: a trial that is not keeps both its weights and its running average untouched, exactly as if
it had not been asked to step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from common.agents.mlp import (
    PARAM_NAMES,
    HotCodes,
    NonzeroInputs,
    takes_rows,
    init_mlp,
    param_shapes,
    views,
    _constant,
    with_ones,
    mlp_forward,
    mlp_backward_rows,
    mlp_backward_sparse,
)


@dataclass(frozen=True)
class Loss:
    """A minibatch loss on the values of the actions taken: "huber" (DQN's TD loss, error clipped to [-1, 1]
    in the gradient) or "squared" (weight * (value - target)^2, Deep TAMER's), averaged over the N rows of
    each trial's minibatch ("mean") or summed ("sum")."""

    kind: str
    reduce: str = "mean"

    def grad(self, pred: np.ndarray, target: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
        """d loss / d pred, float32 [n, N]."""
        if self.kind == "huber":  # (np.clip's own overhead is twice that of these two calls: the same numbers)
            d = pred - target
            np.maximum(d, np.float32(-1), out=d)
            np.minimum(d, np.float32(1), out=d)
        elif weights is None:
            raise ValueError("a squared loss here is weighted: its job needs weights")
        else:
            d = np.float32(2) * weights * (pred - target)
        if self.reduce == "mean":
            d /= np.float32(pred.shape[1])
        return d


HUBER_MEAN = Loss("huber")
SQUARED_MEAN = Loss("squared")
SQUARED_SUM = Loss("squared", "sum")


@dataclass
class FitJob:
    """One optimiser step of `net` on trial rows `rows`: minibatch x [n, N, ...], actions [n, N], targets and
    weights [n, N] (weights None for an unweighted loss). x1, optional: x with a column of ones appended, which
    the numpy MLP uses instead of making it (replay stores it); other networks ignore it."""

    net: ValueNetworks
    rows: np.ndarray
    x: np.ndarray
    actions: np.ndarray
    targets: np.ndarray
    weights: np.ndarray | None
    loss: Loss
    x1: np.ndarray | None = None  # x with its ones column (`with_ones`), where the caller holds it already


class ValueNetworks(Protocol):
    """Per-trial value networks of a batch (row r is trial r's); rows are ascending index arrays."""

    n_actions: int

    def values(self, rows: np.ndarray | None, x: np.ndarray, x1: np.ndarray | None = None) -> np.ndarray:
        """x [n, N, ...] (n = len(rows), all trials when rows is None) -> float32 [n, N, n_actions]. x1, when
        given, is x with a column of ones appended (`with_ones`), for a network that can use it instead of
        making it (the numpy MLP); others ignore it."""

    def fit(self, job: FitJob) -> None:
        """One gradient step of its optimiser on `job`."""

    def sync_from(self, other: ValueNetworks, rows: np.ndarray) -> None:
        """Copy other's weights into rows `rows` (a target network's sync)."""

    def select(self, rows: np.ndarray) -> None: ...

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...

    def policy_state(self, row: int) -> dict[str, np.ndarray]: ...

    def load_policy_state(self, row: int, state: dict) -> None: ...


def pick(values: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """values[i, j, actions[i, j]] for values [n, N, A]: [n, N]."""
    n, N, A = values.shape
    return values.reshape(n * N, A)[_constant("arange", n * N), actions.reshape(-1)].reshape(n, N)


def row_index(rows: np.ndarray | None, total: int):
    """How to address rows (ascending) of `total`: None for all of them, a slice when they are consecutive
    (numpy views, no copies), else the index array."""
    if rows is None or len(rows) == total:
        return None
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


class FlatRMSProp:
    """RMSProp on the rows of a flat [B, P] float32 parameter array (the network's; given at each step): the
    numpy MLP's optimiser part (see the module's doc)."""

    def __init__(self, lr: float = 1e-3, alpha: float = 0.99, eps: float = 1e-8):
        self.lr, self.alpha, self.eps = np.float32(lr), np.float32(alpha), np.float32(eps)
        self.square_avg = np.zeros((0, 0), np.float32)

    def attach(self, shape: tuple[int, int]) -> None:
        """Start with a zero running average for parameters of this [B, P] shape."""
        self.square_avg = np.zeros(shape, np.float32)

    def step_rows(self, flat: np.ndarray, idx, grad: np.ndarray, blocks: tuple | None = None) -> None:
        """Step rows `idx` of `flat` (all when None; a slice or an index array) with `grad` [their number, P].

        All rows or a slice are stepped in place (views, no copies); other selections are gathered,
        stepped and scattered back. The arithmetic is the same either way.

        blocks (count, width, keys): the first count * width columns of a row are `count` blocks of `width`, and
        only the blocks `keys` (flat: row * count + block, distinct) have a nonzero gradient (a wide first
        layer's touched inputs). A zero gradient leaves a weight as it is and only decays its running average
        (alpha sq + 0, and p - 0 / (...) = p, exactly), so the other blocks get just that: the same bits as the
        dense step. blocks (count, width, keys, sums): the same, with the touched blocks' gradients `sums`
        [len(keys), width] given apart and `grad` only the columns after the blocks (no dense gradient is made)."""
        inplace = idx is None or isinstance(idx, slice)
        sel = slice(None) if idx is None else idx
        p = flat[sel]
        sq = self.square_avg[sel]
        if blocks is not None:
            sq *= self.alpha
            count, width, keys = blocks[:3]
            tail = count * width
            self._update(p[:, tail:], sq[:, tail:], grad[:, tail:] if len(blocks) == 3 else grad)
            at = keys // count, keys % count
            p3, sq3 = (a[:, :tail].reshape(len(a), count, width) for a in (p, sq))  # (views)
            p_b, sq_b = p3[at], sq3[at]
            self._update(
                p_b, sq_b, grad[:, :tail].reshape(len(grad), count, width)[at] if len(blocks) == 3 else blocks[3]
            )
            p3[at], sq3[at] = p_b, sq_b
        else:
            sq *= self.alpha  # sq = alpha sq + (1 - alpha) g^2
            self._update(p, sq, grad)
        if not inplace:
            self.square_avg[sel] = sq
            flat[sel] = p

    def _update(self, p: np.ndarray, sq: np.ndarray, grad: np.ndarray) -> None:
        """The step after the decay: sq += (1 - alpha) g^2, p -= lr g / (sqrt(sq) + eps), in place."""
        tmp = grad * grad
        tmp *= np.float32(1) - self.alpha
        sq += tmp
        np.sqrt(sq, out=tmp)  # p = p - g / (sqrt(sq) + eps) lr
        tmp += self.eps
        np.divide(grad, tmp, out=tmp)
        tmp *= self.lr
        p -= tmp

    def select(self, idx: np.ndarray) -> None:
        self.square_avg = self.square_avg[idx]

    def state_dict(self) -> np.ndarray:
        return self.square_avg.copy()

    def load_state_dict(self, state) -> None:
        self.square_avg[...] = np.asarray(state)


class StackedMLP:
    """B MLPs in -> hidden (tanh) -> out, parameters stacked on a leading trial axis (`ValueNetworks`)."""

    def __init__(
        self, in_dim: int, hidden: int, out_dim: int, seeds: list[int], optimiser=None, hot: HotCodes | None = None
    ):
        """hot: inputs come as their codes (`mlp.HotCodes`, a first layer that takes rows), never dense."""
        self.in_dim, self.hidden, self.out_dim = in_dim, hidden, out_dim
        self.hot = hot
        self.n_actions = out_dim
        self.shapes = param_shapes(in_dim, hidden, out_dim)
        per_trial = [init_mlp(in_dim, hidden, out_dim, s) for s in seeds]
        flat = np.stack([np.concatenate([p[k].reshape(-1) for k in PARAM_NAMES]) for p in per_trial])
        self.set_flat(np.ascontiguousarray(flat, np.float32))
        self.opt = optimiser
        if optimiser is not None:
            optimiser.attach(self.flat.shape)

    @property
    def trials(self) -> int:
        return self.flat.shape[0]

    def rows(self, idx) -> dict[str, np.ndarray]:
        """Views of the weights of trials `idx` (None, a slice or an index array; None and slices without
        copying, a slice's views made once per `flat`)."""
        if idx is None:
            return self.params
        if not isinstance(idx, slice):
            return views(self.flat[idx], self.shapes)
        got = self._slice_views.get((idx.start, idx.stop))
        if got is None:
            got = self._slice_views[(idx.start, idx.stop)] = views(self.flat[idx], self.shapes)
        return got

    def set_flat(self, flat: np.ndarray) -> None:
        self.flat = flat
        self.params = views(flat, self.shapes, names=True)
        self._slice_views: dict[tuple, dict[str, np.ndarray]] = {}

    def values(self, rows: np.ndarray | None, x: np.ndarray, x1: np.ndarray | None = None) -> np.ndarray:
        """(`ValueNetworks.values`; x1: `with_ones(x)` where the caller has it.)"""
        params = (
            self.params
            if rows is None or len(rows) == self.flat.shape[0]
            else self.rows(row_index(rows, self.flat.shape[0]))
        )
        if self.hot is not None:
            return mlp_forward(params, x, x, NonzeroInputs.of_codes(x))[1]
        return mlp_forward(params, np.asarray(x, np.float32), x1)[1]

    def fit(self, job: FitJob) -> None:
        fit_together([job])

    def sync_from(self, other: StackedMLP, rows: np.ndarray) -> None:
        self.flat[rows] = other.flat[rows]

    def select(self, idx: np.ndarray) -> None:
        """Keep only the trials `idx` (in that order)."""
        self.set_flat(self.flat[idx])
        if self.opt is not None:
            self.opt.select(idx)

    def state_dict(self) -> dict:
        out = {"flat": self.flat.copy()}
        if self.opt is not None:
            out["opt"] = self.opt.state_dict()
        return out

    def load_state_dict(self, state: dict) -> None:
        self.flat[...] = state["flat"]
        if self.opt is not None and "opt" in state:
            self.opt.load_state_dict(state["opt"])

    def policy_state(self, i: int) -> dict[str, np.ndarray]:
        """Trial i's weights as named float32 arrays (what the learner publishes)."""
        return {k: self.params[k][i].copy() for k in PARAM_NAMES}

    def load_policy_state(self, i: int, state: dict) -> None:
        arrays = {}
        for k in PARAM_NAMES:
            a = np.asarray(state[k])
            if tuple(a.shape) != tuple(self.params[k][i].shape):
                raise ValueError(f"weights {k}: expected shape {tuple(self.params[k][i].shape)}, got {tuple(a.shape)}")
            arrays[k] = a
        for k, a in arrays.items():
            self.params[k][i] = a


def _stackable(jobs: list[FitJob]) -> bool:
    first = jobs[0]
    return all(
        isinstance(j.net, StackedMLP) and j.net.shapes == first.net.shapes and j.x.shape[1:] == first.x.shape[1:]
        for j in jobs
    )


def fit_together(jobs: list[FitJob]) -> None:
    """Run several fits; those on numpy MLPs of one shape (Q and H of the paper) as one stacked computation
    (one forward, one backward: at a few rows, the per-call overhead is what costs). Each row's arithmetic is
    its own either way, so stacking changes speed only."""
    jobs = [j for j in jobs if len(j.rows)]
    if not jobs:
        return
    if not isinstance(jobs[0].net, StackedMLP) or (len(jobs) > 1 and not _stackable(jobs)):
        for j in jobs:
            j.net.fit(j)
        return
    hot = jobs[0].net.hot is not None  # (codes: x is what x1 would be, found without a scan)
    if len(jobs) == 1:  # (the common case, with as few calls as possible: the same arithmetic)
        j = jobs[0]
        r = row_index(j.rows, j.net.flat.shape[0])
        params, x, x1, idx = j.net.rows(r), j.x, j.x1, [r]
    else:
        idx = [row_index(j.rows, j.net.flat.shape[0]) for j in jobs]
        params = views(
            np.concatenate([j.net.flat if r is None else j.net.flat[r] for j, r in zip(jobs, idx)]), jobs[0].net.shapes
        )
        if not hot and all(j.x1 is not None for j in jobs):
            x1 = np.concatenate([j.x1 for j in jobs])
            x = x1[..., :-1]
        else:
            x, x1 = np.concatenate([j.x for j in jobs]), None
    if hot or x1 is None:
        x1 = x if hot else with_ones(x)
    nz = (NonzeroInputs.of_codes(x1) if hot else NonzeroInputs.of(x1)) if takes_rows(params["a1"]) else None
    hidden, out = mlp_forward(params, x, x1, nz)
    # d loss / d out: each row's loss gradient at its action taken, 0 at the other actions (a scatter into
    # zeros at flat positions row * A + action: the same numbers as a mask and np.where, at half the cost).
    d_out = np.zeros_like(out)
    start = 0
    for j in jobs:
        n = len(j.rows)
        at = _constant("offsets", out.shape[1] * n, out.shape[2]) + j.actions.reshape(-1)
        pred = out[start : start + n].reshape(-1)[at].reshape(n, -1)
        d_out[start : start + n].reshape(-1)[at] = j.loss.grad(pred, j.targets, j.weights).reshape(-1)
        start += n
    if nz is not None:  # (a first layer that takes rows: its touched rows' gradients, no dense gradient)
        tail, keys, sums = mlp_backward_sparse(params, hidden, d_out, x1, nz)
        in1, width = params["a1"].shape[1:]
        start = 0
        for j, r in zip(jobs, idx):
            n = len(j.rows)
            lo, hi = np.searchsorted(keys, [start * in1, (start + n) * in1])
            blocks = (in1, width, keys[lo:hi] - start * in1, sums[lo:hi])
            j.net.opt.step_rows(j.net.flat, r, tail[start : start + n], blocks)
            start += n
        return
    grad = mlp_backward_rows(params, x, hidden, d_out, x1)[0]
    start = 0
    for j, r in zip(jobs, idx):
        n = len(j.rows)
        j.net.opt.step_rows(j.net.flat, r, grad[start : start + n])
        start += n
