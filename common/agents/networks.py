"""A stack of independent one-hidden-layer MLPs, one per trial, evaluated as one batched computation.

Trial i's weights are W1[i], b1[i], W2[i], b2[i]; `forward` uses batched matrix products so B trials cost
one call. Each trial is initialised from its own generator, so a trial gets the same weights whether it
runs alone (B = 1) or among others.

Gradients are written out by hand (`mlp_backward`) instead of using autograd: the network is two affine
maps and a tanh, the hand-written backward is a handful of batched products, and it avoids building a
graph on every update (autograd's bookkeeping cost more than the arithmetic at these sizes). Every
operation is either a per-trial batched matrix product or elementwise, never a reduction across trials,
so a trial's numbers do not depend on which or how many trials share the batch.
"""
from __future__ import annotations

import math

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


def mlp_hidden(p: dict[str, torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """tanh(x W1 + b1): [n, N, in] -> [n, N, hidden]."""
    return torch.bmm(x, p["w1"]).add_(p["b1"]).tanh_()


def mlp_forward(p: dict[str, torch.Tensor], x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(hidden activations, outputs) for x: [n, N, in] -> [n, N, hidden], [n, N, out]."""
    h = mlp_hidden(p, x)
    return h, torch.bmm(h, p["w2"]).add_(p["b2"])


def mlp_backward(p: dict[str, torch.Tensor], x: torch.Tensor, h: torch.Tensor,
                 d_out: torch.Tensor) -> dict[str, torch.Tensor]:
    """Gradients of sum(d_out * out) with respect to each trial's weights (what autograd would give).

    Bias gradients are sums over the N rows, written as products with a row of ones so that they are
    per-trial matrix products like the rest.
    """
    n, N, _ = x.shape
    ones = torch.ones(n, 1, N, dtype=x.dtype)
    g_w2 = torch.bmm(h.transpose(1, 2), d_out)
    g_b2 = torch.bmm(ones, d_out)
    d_pre = torch.bmm(d_out, p["w2"].transpose(1, 2))
    d_pre.mul_(1.0 - h * h)
    g_w1 = torch.bmm(x.transpose(1, 2), d_pre)
    g_b1 = torch.bmm(ones, d_pre)
    return {"w1": g_w1, "b1": g_b1, "w2": g_w2, "b2": g_b2}


class StackedMLP:
    """B MLPs in -> hidden (tanh) -> out, parameters stacked on a leading trial axis."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, seeds: list[int]):
        self.in_dim, self.hidden, self.out_dim = in_dim, hidden, out_dim
        per_trial = [init_mlp(in_dim, hidden, out_dim, s) for s in seeds]
        self.params = {name: torch.stack([p[name] for p in per_trial]) for name in PARAM_NAMES}

    @property
    def trials(self) -> int:
        return self.params["w1"].shape[0]

    @torch.no_grad()
    def forward(self, x: torch.Tensor, params: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """x: [B, N, in] -> [B, N, out]."""
        return mlp_forward(self.params if params is None else params, x)[1]

    __call__ = forward

    def rows(self, idx: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """The weights of the trials `idx` (all trials, without copying, when idx is None)."""
        if idx is None:
            return self.params
        return {k: v.index_select(0, idx) for k, v in self.params.items()}

    def select(self, idx: torch.Tensor) -> None:
        """Keep only the trials `idx` (in that order)."""
        self.params = {k: v.index_select(0, idx) for k, v in self.params.items()}

    def detached_copy(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().clone() for k, v in self.params.items()}

    def trial_state(self, i: int) -> dict[str, torch.Tensor]:
        """Trial i's weights as plain tensors (what the learner publishes)."""
        return {k: v[i].detach().clone() for k, v in self.params.items()}

    def load_trial_state(self, i: int, state: dict[str, torch.Tensor]) -> None:
        with torch.no_grad():
            for k, v in self.params.items():
                if tuple(state[k].shape) != tuple(v[i].shape):
                    raise ValueError(f"weights {k}: expected shape {tuple(v[i].shape)}, got {tuple(state[k].shape)}")
                v[i].copy_(state[k])
