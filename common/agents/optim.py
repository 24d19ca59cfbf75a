"""RMSProp over stacked trial parameters, stepping only the trials selected (the agent's optimiser part).

The update of torch.optim.RMSprop (alpha 0.99, eps 1e-8, no momentum, the same operations in the same order:
tests/core/test_agents.py checks it against torch): a trial that is not selected keeps both its weights and
its running average untouched, exactly as if it had not been asked to step.
"""
from __future__ import annotations

import numpy as np


class FlatRMSProp:
    """RMSProp on the rows of a flat [B, P] float32 parameter array (the network's; given at each step)."""

    def __init__(self, lr: float = 1e-3, alpha: float = 0.99, eps: float = 1e-8):
        self.lr, self.alpha, self.eps = np.float32(lr), np.float32(alpha), np.float32(eps)
        self.square_avg = np.zeros((0, 0), np.float32)

    def attach(self, shape: tuple[int, int]) -> None:
        """Start with a zero running average for parameters of this [B, P] shape."""
        self.square_avg = np.zeros(shape, np.float32)

    def step_rows(self, flat: np.ndarray, idx, grad: np.ndarray) -> None:
        """Step rows `idx` of `flat` (all when None; a slice or an index array) with `grad` [their number, P].

        All rows or a slice are stepped in place (views, no copies); other selections are gathered,
        stepped and scattered back. The arithmetic is the same either way."""
        inplace = idx is None or isinstance(idx, slice)
        sel = slice(None) if idx is None else idx
        p = flat[sel]
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
            flat[sel] = p

    def select(self, idx: np.ndarray) -> None:
        self.square_avg = self.square_avg[idx]

    def state_dict(self) -> np.ndarray:
        return self.square_avg.copy()

    def load_state_dict(self, state) -> None:
        self.square_avg[...] = np.asarray(state)
