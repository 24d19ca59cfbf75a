"""What a person's screen showed: the recent steps with the system time each appeared (pure; no transport).

The console keeps one per person from the page's paint reports; the perception service keeps one per screen
from the console's `Shown` messages. A feedback stamped t lists the steps that were on screen during the
window the assumed delay can reach back to, `[t - span, t]` (and the step already showing when it began), so
the learner can credit it in seconds over each step's on-screen interval.
"""

from __future__ import annotations

import collections

from common.protocol import MAX_SHOWN, ShownStep


class ScreenTimeline:
    """Recent (actor incarnation, Step.seq, system time shown), in the order they appeared."""

    def __init__(self, capacity: int = 4 * MAX_SHOWN):
        self._items: collections.deque[tuple[str, int, float]] = collections.deque(maxlen=capacity)

    def __len__(self) -> int:
        return len(self._items)

    def add(self, actor: str, seq: int, t_shown: float) -> bool:
        """Record a paint. Ignored (False) unless it is newer in time, and in seq for the same actor."""
        if self._items:
            a, q, t = self._items[-1]
            if t_shown < t or (a == actor and seq <= q):
                return False
        self._items.append((actor, int(seq), float(t_shown)))
        return True

    def window(self, t: float, span: float) -> tuple[str | None, list[ShownStep]]:
        """The steps a feedback at t may refer to: the actor of the step on screen at t, and that actor's
        steps shown in [t - span, t] plus the one on screen at t - span, oldest first (at most MAX_SHOWN)."""
        on_screen = [it for it in self._items if it[2] <= t]
        if not on_screen:
            return None, []
        actor = on_screen[-1][0]
        mine = [it for it in on_screen if it[0] == actor]
        first = 0
        for k, it in enumerate(mine):
            if it[2] <= t - span:
                first = k
        picked = mine[first:][-MAX_SHOWN:]
        return actor, [ShownStep(q, ts) for _, q, ts in picked]
