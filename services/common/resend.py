"""At-least-once delivery across a restarted receiver (docs/faults.md): Step, Feedback, Ingest and EpisodeSummary
are published once, in order, on BLOCK keys; when a receiver that matters (learner, recorder) restarts, the
publishers re-send what they published in the last `window` seconds, and every receiver drops what it already
has (`duplicate`), so nobody double-counts."""

from __future__ import annotations

import collections
import time
from typing import Any


class ResendRing:
    """What a publisher sent in the last `window` seconds (at most `max_items` messages), to publish again
    when a receiver comes (back) alive. Bounded in both time and count."""

    def __init__(self, window: float = 30.0, max_items: int = 20000):
        self.window, self.max_items = float(window), int(max_items)
        self._items: collections.deque[tuple[float, Any, bytes]] = collections.deque()
        self.resent = 0

    def __len__(self) -> int:
        return len(self._items)

    def add(self, publisher: Any, data: bytes) -> None:
        now = time.monotonic()
        self._items.append((now, publisher, data))
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self._items and (len(self._items) > self.max_items or now - self._items[0][0] > self.window):
            self._items.popleft()

    def resend(self, last: int | None = None) -> int:
        """Publish everything still in the window again (only the `last` newest if given), in the original order.
        Returns how many."""
        self._trim(time.monotonic())
        items = list(self._items)
        if last is not None:
            items = items[len(items) - min(max(last, 0), len(items)) :]
        for _, publisher, data in items:
            publisher.put(data)
        self.resent += len(items)
        return len(items)


def publish_kept(publisher: Any, message: Any, ring: ResendRing | None) -> bytes:
    """Encode (validates), publish, and keep for re-sending."""
    data = message.encode()
    publisher.put(data)
    if ring is not None:
        ring.add(publisher, data)
    return data
