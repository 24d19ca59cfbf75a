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
