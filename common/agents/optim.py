"""RMSProp over stacked trial parameters, stepping only the trials a mask selects.

Same update as torch.optim.RMSprop (alpha 0.99, eps 1e-8, no momentum): a trial that is not selected
keeps both its weights and its running average untouched, exactly as if it had not been asked to step.
"""
from __future__ import annotations

import torch


class MaskedRMSProp:
    def __init__(self, params: dict[str, torch.Tensor], lr: float = 1e-3, alpha: float = 0.99,
                 eps: float = 1e-8):
        self.params = params
        self.lr, self.alpha, self.eps = lr, alpha, eps
        self.square_avg = {k: torch.zeros_like(v) for k, v in params.items()}

    def zero_grad(self) -> None:
        for p in self.params.values():
            p.grad = None

    @torch.no_grad()
    def step(self, mask: torch.Tensor) -> None:
        """mask: bool [B]; trials with False are left exactly as they were."""
        for name, p in self.params.items():
            g = p.grad
            if g is None:
                continue
            m = mask.view(-1, *([1] * (p.dim() - 1)))
            sq = self.square_avg[name]
            new_sq = sq * self.alpha + g * g * (1 - self.alpha)
            update = g / (new_sq.sqrt() + self.eps) * self.lr
            sq.copy_(torch.where(m, new_sq, sq))
            p.sub_(torch.where(m, update, torch.zeros_like(update)))

    def state_dict(self) -> dict:
        return {k: v.clone() for k, v in self.square_avg.items()}

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            self.square_avg[k].copy_(v)
