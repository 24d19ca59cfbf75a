"""When the learner's weights go into the log: a WeightsSnapshot on `hitl/<run>/snapshot` at a bounded rate.

The actor needs the weights after almost every step (lockstep), on `hitl/<run>/weights`, which the recorder does
not log. The log gets a snapshot: the first weights, then every `snapshot_every` steps learned, at each episode end
(summary numbers only, no raw bytes), on request (`hitl/<run>/request`, at most one per `REQUEST_GAP` s) and the
final weights (which `replay retrain` compares with its own). No learner state is touched: only what is published.
"""

from __future__ import annotations

import time
from typing import Any
from collections.abc import Callable

import numpy as np

from common.protocol import ProtocolError, Request, TensorSummary, WeightsSnapshot

REQUEST_GAP = 0.5  # s between two snapshots made on request


def tensor_summaries(tensors: dict[str, np.ndarray]) -> list[TensorSummary]:
    """Mean, std, min, max and norm of each tensor, in float64: the numbers of `a.mean()`, `a.std()`, ... bit for
    bit, computed with the reductions those make (at every episode end their call overhead was the cost)."""
    out = []
    for name, t in tensors.items():
        a = np.asarray(t, np.float64)
        n = a.size
        if not n:
            out.append(TensorSummary(name, list(a.shape), 0.0, 0.0, 0.0, 0.0, 0.0))
            continue
        mean = np.add.reduce(a, axis=None) / n
        d = a - mean
        d *= d
        out.append(
            TensorSummary(
                name,
                list(a.shape),
                float(mean),
                float(np.sqrt(np.add.reduce(d, axis=None) / n)),
                float(np.minimum.reduce(a, axis=None)),
                float(np.maximum.reduce(a, axis=None)),
                float(np.sqrt(np.add.reduce(a * a, axis=None))),
            )
        )
    return out


class Snapshots:
    """Decides and publishes WeightsSnapshots. `publish(message)` sends one (the service's publish_kept)."""

    def __init__(self, run: str, incarnation: str, every: int, publish: Callable[[WeightsSnapshot], object]):
        self.run, self.incarnation, self.every, self._publish = run, incarnation, every, publish
        self.last_version: int | None = None  # of the last snapshot with raw weights
        self._last_request = 0.0
        self.counts: dict[str, int] = {}

    def _send(self, reason: str, version: int, tensors: dict[str, np.ndarray], raw: bytes | None) -> None:
        self._publish(
            WeightsSnapshot(
                run=self.run,
                incarnation=self.incarnation,
                version=version,
                reason=reason,
                t_published=time.time(),
                tensors=tensor_summaries(tensors),
                weights=raw,
            )
        )
        self.counts[reason] = self.counts.get(reason, 0) + 1
        if raw is not None:
            self.last_version = version

    def on_weights(self, version: int, tensors: dict[str, np.ndarray], raw: bytes) -> None:
        """After each Weights publication: a snapshot if it is the first or `every` steps have passed."""
        if self.last_version is None:
            self._send("start", version, tensors, raw)
        elif version - self.last_version >= self.every:
            self._send("every", version, tensors, raw)

    def on_episode(self, version: int, tensors: dict[str, np.ndarray]) -> None:
        self._send("episode", version, tensors, None)

    def on_requests(self, items: list[Any], version: int, weights: Callable[[], tuple[dict, bytes]]) -> None:
        """Requests received (inbox items); answers at most one per REQUEST_GAP s."""
        asked = False
        for it in items:
            try:
                asked |= isinstance(it.decode(), Request)
            except ProtocolError:
                continue
        if asked and time.monotonic() - self._last_request >= REQUEST_GAP:
            self._last_request = time.monotonic()
            tensors, raw = weights()
            self._send("request", version, tensors, raw)

    def final(self, version: int, tensors: dict[str, np.ndarray], raw: bytes) -> None:
        self._send("final", version, tensors, raw)
