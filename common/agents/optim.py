"""RMSProp over stacked trial parameters, stepping only the trials selected.

Same update as torch.optim.RMSprop (alpha 0.99, eps 1e-8, no momentum): a trial that is not selected
keeps both its weights and its running average untouched, exactly as if it had not been asked to step.
Two entry points: `step(mask)` reads `.grad` (autograd users), `step_rows(idx, grads)` takes gradients
for the selected trials only (the agent's hand-written backward).
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

    def _update(self, p: torch.Tensor, sq: torch.Tensor, g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        new_sq = sq * self.alpha + g * g * (1 - self.alpha)
        return p - g / (new_sq.sqrt() + self.eps) * self.lr, new_sq

    @torch.no_grad()
    def step(self, mask: torch.Tensor) -> None:
        """mask: bool [B]; trials with False are left exactly as they were."""
        for name, p in self.params.items():
            g = p.grad
            if g is None:
                continue
            m = mask.view(-1, *([1] * (p.dim() - 1)))
            sq = self.square_avg[name]
            new_p, new_sq = self._update(p, sq, g)
            sq.copy_(torch.where(m, new_sq, sq))
            p.copy_(torch.where(m, new_p, p))

    @torch.no_grad()
    def step_rows(self, idx: torch.Tensor | None, grads: dict[str, torch.Tensor]) -> None:
        """Step trials `idx` (all when None) with `grads[name]` of shape [len(idx), ...]."""
        for name, g in grads.items():
            p, sq = self.params[name], self.square_avg[name]
            if idx is None:
                new_p, new_sq = self._update(p, sq, g)
                p.copy_(new_p)
                sq.copy_(new_sq)
            else:
                new_p, new_sq = self._update(p.index_select(0, idx), sq.index_select(0, idx), g)
                p.index_copy_(0, idx, new_p)
                sq.index_copy_(0, idx, new_sq)

    def select(self, idx: torch.Tensor, params: dict[str, torch.Tensor]) -> None:
        """Keep only trials `idx`; `params` are the (already selected) parameter tensors."""
        self.params = params
        self.square_avg = {k: v.index_select(0, idx) for k, v in self.square_avg.items()}

    def state_dict(self) -> dict:
        return {k: v.clone() for k, v in self.square_avg.items()}

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            self.square_avg[k].copy_(v)
