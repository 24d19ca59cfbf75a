"""RMSProp over stacked trial parameters, stepping only the trials selected.

The update of torch.optim.RMSprop (alpha 0.99, eps 1e-8, no momentum, same fused operations): a trial
that is not selected keeps both its weights and its running average untouched, exactly as if it had not
been asked to step. Two front ends: `MaskedRMSProp` over a dict of parameters with `.grad` (autograd
users), and `FlatRMSProp` over one flat [B, P] numpy array with gradients for selected rows (the agent).
"""
from __future__ import annotations

import numpy as np
import torch


def rmsprop_update(p: torch.Tensor, sq: torch.Tensor, g: torch.Tensor, lr: float, alpha: float,
                   eps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(new parameters, new running average of squared gradients); inputs are left untouched."""
    new_sq = torch.addcmul(sq * alpha, g, g, value=1 - alpha)
    return torch.addcdiv(p, g, new_sq.sqrt().add_(eps), value=-lr), new_sq


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
            new_p, new_sq = rmsprop_update(p, sq, g, self.lr, self.alpha, self.eps)
            sq.copy_(torch.where(m, new_sq, sq))
            p.copy_(torch.where(m, new_p, p))

    def state_dict(self) -> dict:
        return {k: v.clone() for k, v in self.square_avg.items()}

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            self.square_avg[k].copy_(v)


class FlatRMSProp:
    """The same update on the rows of a flat [B, P] float32 numpy array owned by a `StackedMLP`."""

    def __init__(self, net, lr: float = 1e-3, alpha: float = 0.99, eps: float = 1e-8):
        self.net = net
        self.lr, self.alpha, self.eps = np.float32(lr), np.float32(alpha), np.float32(eps)
        self.square_avg = np.zeros_like(net.flat)

    def step_rows(self, idx, grad: np.ndarray) -> None:
        """Step trials `idx` (all when None; a slice or an index array) with `grad` [their number, P].

        All rows or a slice are stepped in place (views, no copies); other selections are gathered,
        stepped and scattered back. The arithmetic is the same either way."""
        inplace = idx is None or isinstance(idx, slice)
        sel = slice(None) if idx is None else idx
        p = self.net.flat[sel]
        sq = self.square_avg[sel]
        sq *= self.alpha                                  # sq = alpha sq + (1 - alpha) g^2
        tmp = grad * grad
        tmp *= np.float32(1) - self.alpha
        sq += tmp
        np.sqrt(sq, out=tmp)                              # p = p - g / (sqrt(sq) + eps) lr
        tmp += self.eps
        np.divide(grad, tmp, out=tmp)
        tmp *= self.lr
        p -= tmp
        if not inplace:
            self.square_avg[sel] = sq
            self.net.flat[sel] = p

    def select(self, idx: np.ndarray) -> None:
        self.square_avg = self.square_avg[idx]

    def state_dict(self) -> np.ndarray:
        return self.square_avg.copy()

    def load_state_dict(self, state) -> None:
        self.square_avg[...] = np.asarray(state)
