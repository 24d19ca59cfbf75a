"""The step clock: wall-clock times mapped onto step numbers, so the live system keeps the in-process
runner's virtual-time semantics on real timestamps.

Step k's action was taken at wall time t_k; on the step clock it is at k, and a time between two actions is
placed linearly between them: tau(t) = k + (t - t_k) / (t_{k+1} - t_k) for t_k <= t < t_{k+1}. At a fixed
actor rate this is wall time divided by the step period (plus a constant); at "as fast as possible" it makes
step durations irrelevant, so a delay of d steps means d steps whatever the machine's speed.

Only defined where both neighbouring actions are known: a time at or after the newest action is not yet
placeable (the caller holds it until a newer step arrives).
"""

from __future__ import annotations

import bisect
import math
from collections import deque


class StepClock:
    """Recent (step number, wall time) pairs, consecutive numbers, strictly increasing times."""

    def __init__(self, capacity: int = 64):
        if capacity < 2:
            raise ValueError("capacity must be >= 2")
        self.capacity = capacity
        self._index: deque[int] = deque()
        self._time: deque[float] = deque()

    def __len__(self) -> int:
        return len(self._index)

    def reset(self) -> None:
        self._index.clear()
        self._time.clear()

    def push(self, index: int, t_wall: float) -> None:
        """Step `index` acted at `t_wall`. A non-consecutive index or a time not after the previous one starts
        the clock afresh (the steps in between are unknown)."""
        if self._index and (index != self._index[-1] + 1 or not t_wall > self._time[-1]):
            self.reset()
        self._index.append(int(index))
        self._time.append(float(t_wall))
        if len(self._index) > self.capacity:
            self._index.popleft()
            self._time.popleft()

    @property
    def newest_index(self) -> int | None:
        return self._index[-1] if self._index else None

    @property
    def newest_time(self) -> float | None:
        return self._time[-1] if self._time else None

    @property
    def oldest_index(self) -> int | None:
        return self._index[0] if self._index else None

    def placeable(self, t_wall: float) -> bool:
        """True when t_wall lies before the newest action (so its interval is known)."""
        return bool(self._time) and t_wall < self._time[-1]

    def to_steps(self, t_wall: float) -> float:
        """The step-clock time of `t_wall`. Before the oldest held action: one step before it (the credit
        function then finds nothing to credit). Raises ValueError if not `placeable`."""
        if not self.placeable(t_wall):
            raise ValueError("time at or after the newest step is not placeable yet")
        times = self._time
        if t_wall < times[0]:
            return float(self._index[0]) - 1.0
        j = bisect.bisect_right(times, t_wall) - 1  # times[j] <= t_wall < times[j + 1]
        return self._index[j] + (t_wall - times[j]) / (times[j + 1] - times[j])

    def to_wall(self, tau: float) -> float | None:
        """The wall time of step-clock time `tau`, or None while step ceil(tau) has not been seen (or tau is
        older than the clock holds)."""
        if not self._index or not math.isfinite(tau):
            return None
        k = math.floor(tau)
        if k < self._index[0] or k + 1 > self._index[-1]:
            if k == self._index[-1] and tau == k:
                return self._time[-1]
            return None
        j = k - self._index[0]
        t0, t1 = self._time[j], self._time[j + 1]
        return t0 + (tau - k) * (t1 - t0)
