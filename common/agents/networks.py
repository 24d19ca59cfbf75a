"""A stack of independent one-hidden-layer MLPs, one per trial, evaluated as one batched computation.

Trial i's weights are W1[i], b1[i], W2[i], b2[i]. Each trial is initialised from its own torch
generator with PyTorch's nn.Linear default (so a trial gets the same weights alone or among others, and
the same as a torch model of the paper's network), then kept as float32 numpy arrays: all of a trial's
weights live in one row of a flat [B, P] array (`flat`), and `params` are views into it, so selecting
trials, an optimiser step or a target-network copy is one operation.

The arithmetic is numpy, written out by hand: forward is one batched product per layer (the first with
the augmented matrix [W1; b1] against the input with a ones column appended), and `mlp_backward` is the exact
gradient (what autograd computes for the same loss). At these sizes (a few to a hundred trials, 100
hidden units, minibatches of 32) per-call overhead dominates the arithmetic; numpy's overhead per call
is several times lower than torch's, which matters most for the last, slow trials of a batch. Every
operation is a per-trial matrix product or elementwise, never a reduction across trials, so a trial's
numbers do not depend on which or how many trials share its batch (tests/experiments/test_batching.py).
"""
from __future__ import annotations

import math

import numpy as np
import torch

PARAM_NAMES = ("w1", "b1", "w2", "b2")


def init_mlp(in_dim: int, hidden: int, out_dim: int, seed: int) -> dict[str, torch.Tensor]:
    """PyTorch's nn.Linear default initialisation (uniform +-1/sqrt(fan_in)) for one trial."""
    g = torch.Generator().manual_seed(int(seed) % (2**63))
    b_in, b_h = 1.0 / math.sqrt(in_dim), 1.0 / math.sqrt(hidden)
    return {
        "w1": (torch.rand(in_dim, hidden, generator=g) * 2 - 1) * b_in,
        "b1": (torch.rand(1, hidden, generator=g) * 2 - 1) * b_in,
        "w2": (torch.rand(hidden, out_dim, generator=g) * 2 - 1) * b_h,
        "b2": (torch.rand(1, out_dim, generator=g) * 2 - 1) * b_h,
    }


def param_shapes(in_dim: int, hidden: int, out_dim: int) -> dict[str, tuple[int, int]]:
    return {"w1": (in_dim, hidden), "b1": (1, hidden), "w2": (hidden, out_dim), "b2": (1, out_dim)}


def views(flat: np.ndarray, shapes: dict[str, tuple[int, int]], names: bool = False) -> dict[str, np.ndarray]:
    """Views into the rows of a flat [n, P] parameter array: the augmented first-layer matrix
    a1 = [w1; b1] ([n, in + 1, hidden]), w2 and b2 (what `mlp_forward` and `mlp_backward` use), and
    with names=True also w1 and b1."""
    n = flat.shape[0]
    (i, h), (_, k) = shapes["w1"], shapes["w2"]
    o = (i + 1) * h
    out = {"a1": flat[:, :o].reshape(n, i + 1, h), "w2": flat[:, o:o + h * k].reshape(n, h, k),
           "b2": flat[:, o + h * k:].reshape(n, 1, k)}
    if names:
        out["w1"] = flat[:, :i * h].reshape(n, i, h)
        out["b1"] = flat[:, i * h:o].reshape(n, 1, h)
    return out


def with_ones(x: np.ndarray) -> np.ndarray:
    """x [n, N, k] with a column of ones appended (the bias input): [n, N, k + 1]."""
    out = np.empty((*x.shape[:-1], x.shape[-1] + 1), np.float32)
    out[..., :-1] = x
    out[..., -1] = 1.0
    return out


def mlp_forward(p: dict[str, np.ndarray], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(hidden activations, outputs) for x: [n, N, in] -> [n, N, hidden], [n, N, out]."""
    h = with_ones(x) @ p["a1"]
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


def mlp_backward(p: dict[str, np.ndarray], x: np.ndarray, h: np.ndarray, d_out: np.ndarray) -> np.ndarray:
    """Gradient of sum(d_out * out) with respect to each trial's weights, flat [n, P] (w1, b1, w2, b2).

    h is `mlp_forward`'s first output. Bias gradients are sums over the N rows, written as products
    (with the ones column of the augmented input, or a row of ones) so that every reduction is a
    per-trial matrix product."""
    n, N = x.shape[:2]
    g_w2 = h.transpose(0, 2, 1) @ d_out                              # [n, hidden, out]
    g_b2 = np.ones((n, 1, N), np.float32) @ d_out                    # [n, 1, out]
    d_pre = d_out @ p["w2"].transpose(0, 2, 1)                       # [n, N, hidden]
    slope = h * h
    np.subtract(np.float32(1), slope, out=slope)                     # tanh' = 1 - tanh^2
    d_pre *= slope
    g1 = with_ones(x).transpose(0, 2, 1) @ d_pre                     # [n, in + 1, hidden] = (w1; b1)
    return np.concatenate([g1.reshape(n, -1), g_w2.reshape(n, -1), g_b2.reshape(n, -1)], axis=1)


class StackedMLP:
    """B MLPs in -> hidden (tanh) -> out, parameters stacked on a leading trial axis."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, seeds: list[int]):
        self.in_dim, self.hidden, self.out_dim = in_dim, hidden, out_dim
        self.shapes = param_shapes(in_dim, hidden, out_dim)
        per_trial = [init_mlp(in_dim, hidden, out_dim, s) for s in seeds]
        flat = torch.stack([torch.cat([p[k].reshape(-1) for k in PARAM_NAMES]) for p in per_trial])
        self.set_flat(np.ascontiguousarray(flat.numpy(), np.float32))

    @property
    def trials(self) -> int:
        return self.flat.shape[0]

    def forward(self, x, params: dict[str, np.ndarray] | None = None):
        """x: [B, N, in] -> [B, N, out] (numpy in, numpy out; a torch tensor in gives a tensor out)."""
        as_torch = isinstance(x, torch.Tensor)
        xn = x.detach().numpy() if as_torch else x
        out = mlp_forward(self.params if params is None else params, np.asarray(xn, np.float32))[1]
        return torch.from_numpy(out) if as_torch else out

    __call__ = forward

    def rows(self, idx: np.ndarray | None) -> dict[str, np.ndarray]:
        """Views of the weights of trials `idx` (of all trials, without copying, when idx is None)."""
        return self.params if idx is None else views(self.flat[idx], self.shapes)

    def set_flat(self, flat: np.ndarray) -> None:
        self.flat = flat
        self.params = views(flat, self.shapes, names=True)

    def select(self, idx: np.ndarray) -> None:
        """Keep only the trials `idx` (in that order)."""
        self.set_flat(self.flat[idx])

    def detached_copy(self) -> dict[str, np.ndarray]:
        return {k: self.params[k].copy() for k in PARAM_NAMES}

    def trial_state(self, i: int) -> dict[str, torch.Tensor]:
        """Trial i's weights as torch tensors (what the learner publishes)."""
        return {k: torch.from_numpy(self.params[k][i].copy()) for k in PARAM_NAMES}

    def load_trial_state(self, i: int, state: dict) -> None:
        arrays = {}
        for k in PARAM_NAMES:
            v = state[k]
            a = v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else np.asarray(v)
            if tuple(a.shape) != tuple(self.params[k][i].shape):
                raise ValueError(f"weights {k}: expected shape {tuple(self.params[k][i].shape)}, got {tuple(a.shape)}")
            arrays[k] = a
        for k, a in arrays.items():
            self.params[k][i] = a
