"""A stack of independent one-hidden-layer MLPs, one per trial, evaluated as one batched computation.

Trial i's weights are W1[i], b1[i], W2[i], b2[i]; `forward` uses batched matrix products so B trials cost
one call. Each trial is initialised from its own generator, so a trial gets the same weights whether it
runs alone (B = 1) or among others.
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


class StackedMLP:
    """B MLPs in -> hidden (tanh) -> out, parameters stacked on a leading trial axis."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, seeds: list[int]):
        self.in_dim, self.hidden, self.out_dim = in_dim, hidden, out_dim
        per_trial = [init_mlp(in_dim, hidden, out_dim, s) for s in seeds]
        self.params = {name: torch.stack([p[name] for p in per_trial]).requires_grad_(True)
                       for name in PARAM_NAMES}

    @property
    def trials(self) -> int:
        return self.params["w1"].shape[0]

    def forward(self, x: torch.Tensor, params: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """x: [B, N, in] -> [B, N, out]."""
        p = self.params if params is None else params
        h = torch.tanh(torch.baddbmm(p["b1"], x, p["w1"]))
        return torch.baddbmm(p["b2"], h, p["w2"])

    __call__ = forward

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
