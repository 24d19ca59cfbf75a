"""Liveliness watches: which services came (back) alive; the statuses waiting in an inbox, decoded. (Which
incarnations of a service have announced themselves: `services.common.gate.IncarnationWatch`.)"""

from __future__ import annotations

import collections
import threading
import time
from typing import TYPE_CHECKING, Any
from collections.abc import Callable, Iterable

from common.protocol import ProtocolError, ServiceStatus

if TYPE_CHECKING:
    from common.wire.delivery import ResendRing


class AliveWatch:
    """Counts liveliness PUTs of the named services (`hitl/<run>/alive/<name>`): a service (re)starting.
    `take()` returns the names that came alive since the last call (callback thread -> service thread)."""

    def __init__(self, session: Any, run: str, names: Iterable[str]):
        from services.common.runtime import alive_key

        self.names = set(names)
        self._lock = threading.Lock()
        self._came: list[str] = []
        self.seen: collections.Counter[str] = collections.Counter()
        self.alive: set[str] = set()  # holding their token now
        self.gone_since: dict[str, float] = {}  # monotonic time each one lost its token
        self._sub = session.liveliness().declare_subscriber(alive_key(run), self._on_sample, history=True)

    def _on_sample(self, sample: Any) -> None:
        import zenoh

        name = str(sample.key_expr).rsplit("/", 1)[-1]
        if name not in self.names:
            return
        with self._lock:
            if sample.kind != zenoh.SampleKind.PUT:
                self.alive.discard(name)
                self.gone_since[name] = time.monotonic()
                return
            self.alive.add(name)
            self.gone_since.pop(name, None)
            self.seen[name] += 1
            if self.seen[name] > 1:  # a restart (the first token is the service starting with us)
                self._came.append(name)

    def take(self) -> list[str]:
        """Names that came back (a new token after an earlier one) since the last call."""
        with self._lock:
            out, self._came = self._came, []
        return out

    def is_alive(self, name: str) -> bool:
        with self._lock:
            return name in self.alive

    def before_exit(self, ring: ResendRing, timeout: float, say: Callable[[str], None] | None = None) -> None:
        """Leaving with a recorder down would lose what it missed: wait (at most `timeout` s) for it to come
        back, then re-send the ring to it."""
        if "recorder" not in self.names or not len(ring) or not self.seen["recorder"]:
            return
        deadline = time.monotonic() + timeout
        if not self.is_alive("recorder") and say is not None:
            say(f"waiting up to {timeout:.0f} s for the recorder to come back before leaving")
        while not self.is_alive("recorder") and time.monotonic() < deadline:
            time.sleep(0.05)
        if self.take():
            ring.resend()

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


def decoded_statuses(inbox: Any, counters: dict) -> Iterable[ServiceStatus]:
    """The statuses waiting in `inbox`, decoded; one that does not decode is counted as
    `rejected_status_<reason>` and dropped."""
    for item in inbox.drain():
        try:
            yield item.decode()
        except ProtocolError as e:
            counters[f"rejected_status_{e.reason}"] += 1
