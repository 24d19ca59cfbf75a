"""What the pages show of the agent: its Q and H per action and alpha_h at the newest observation, computed (as
the actor would) from the newest weights the console adopted, sent with every step and, for newer weights,
at most every PREFS_EVERY s.

A paced learner publishes weights about twice a step (idle-time updates); each set sent at once was a forward
pass here and a message to every page, which shows preferences at most every 0.5 s anyway (static/console.js).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

PREFS_EVERY = 0.5


class PrefsFeed:
    def __init__(self, agent: Any, weights: Any, loop: asyncio.AbstractEventLoop, broadcast: Callable[[dict], None]):
        self.agent, self.weights, self.loop, self.broadcast = agent, weights, loop, broadcast
        self.obs: Any = None  # the newest step's observation (None before the first step)
        self.timer: asyncio.TimerHandle | None = None
        self.sent_at = 0.0

    def current(self) -> dict:
        if self.obs is None:
            return {"type": "prefs", "q": None, "h": None}
        q, h, aq, ah = self.agent.preferences(0, self.obs)
        return {
            "type": "prefs",
            "q": [round(float(x), 4) for x in q],
            "h": [round(float(x), 4) for x in h],
            "alpha_q": aq,
            "alpha_h": round(ah, 5),
            "weights_version": self.weights.version,
        }

    def weights_adopted(self, pages: int) -> None:
        """Newer weights: the pages get them PREFS_EVERY s after the last preferences sent, or with the next step."""
        if pages and self.timer is None:
            wait = self.sent_at + PREFS_EVERY - time.monotonic()
            self.timer = self.loop.call_later(max(0.0, wait), self.send_now, pages)

    def send_now(self, pages: int) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        self.sent_at = time.monotonic()
        if pages:  # (a forward pass: none for nobody)
            self.broadcast(self.current())
