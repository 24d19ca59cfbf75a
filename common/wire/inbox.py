"""The bounded queue between a zenoh callback subscriber and a service's own thread, and the process's
authentication default (common/wire/auth.py) that every publisher and inbox uses."""

from __future__ import annotations

import collections
import dataclasses
import threading
import time
from typing import Any

from common.protocol import KEYS, ProtocolError, decode

QUEUE_POLICIES = ("block", "drop_oldest")


# -- authentication (common/wire/auth.py): the process's own credential, used by default by every publisher and inbox --

_DEFAULT_AUTH: list[Any] = [None]


def set_default_auth(auth: Any) -> None:
    """Sign everything this process publishes and check everything it receives with ``auth``
    (a :class:`common.wire.auth.Auth`; None: neither). A service sets it once, from its credential file."""
    _DEFAULT_AUTH[0] = auth


def default_auth() -> Any:
    return _DEFAULT_AUTH[0]


@dataclasses.dataclass(frozen=True)
class Received:
    """A sample as it arrived: raw bytes, key, local arrival time, and zenoh's timestamp (s) if any."""

    key: str
    data: bytes
    t_recv: float  # time.time() at arrival, in the zenoh callback
    t_zenoh: float | None  # the sample's zenoh timestamp in seconds since the epoch (None if not stamped)

    def decode(self) -> Any:
        return decode(self.key, self.data)


def _zenoh_seconds(ts: Any) -> float | None:
    if ts is None:
        return None
    try:
        return ts.get_time().timestamp()
    except Exception:
        return None


class Inbox:
    """A bounded queue between a zenoh callback subscriber (producer) and the service's own thread.

    The zenoh callback only copies the payload and appends; decoding happens in the consumer
    (:meth:`get_message`), which counts drops by ProtocolError reason.

    Policies when full:

    - ``"block"``: the callback waits for room, up to ``block_timeout`` s, then drops the new sample and
      counts ``dropped_full``. Waiting in the callback stalls that session's delivery, which with
      publishers on CongestionControl.BLOCK pushes back on them: nothing is lost while the consumer keeps up
      within ``block_timeout``. Use for step, feedback, weights into a learner or recorder.
    - ``"drop_oldest"``: never waits; evicts the oldest sample and counts ``dropped_oldest``. Use for
      status, camera, perception, and (maxsize 1) for an actor that only wants the newest weights.

    Counters (``counters`` dict): ``received``, ``dropped_oldest``, ``dropped_full``, ``dropped_closed``,
    ``decoded``, and ``dropped_<reason>`` for each ProtocolError reason seen by :meth:`get_message`.
    """

    def __init__(self, maxsize: int = 1024, policy: str = "block", *, block_timeout: float = 5.0, auth: Any = None):
        if policy not in QUEUE_POLICIES:
            raise ValueError(f"policy must be one of {QUEUE_POLICIES}")
        if maxsize < 1:
            raise ValueError("maxsize must be >= 1")
        self.maxsize, self.policy, self.block_timeout = maxsize, policy, block_timeout
        self._items: collections.deque[Received] = collections.deque()
        self._cond = threading.Condition()
        self._closed = False
        self.counters: collections.Counter[str] = collections.Counter()
        # Checked in zenoh's callback, before the sample is queued: a forgery never takes a real sample's place.
        self.auth = auth if auth is not None else default_auth()
        self._window: dict = {}  # this subscription's replay state (common.wire.auth.Auth.check)

    # producer side (zenoh's callback thread)
    def handler(self) -> Any:
        """What to pass to ``declare_subscriber``: :meth:`callback` run directly on zenoh's network thread
        (``indirect=False``). zenoh-python's default (``indirect=True``) hands every sample to a Python thread
        through an unbounded channel: a slow consumer then grows that channel without limit and never pushes
        back (measured here: 5000 puts of 500 B on a BLOCK publisher returned in 0.03 s to a subscriber taking
        5 ms each). Run directly, a full ``block`` inbox stalls the network thread, and Zenoh's BLOCK congestion
        control carries the back-pressure to the publishers (within Zenoh's and the kernel's bounded buffers)."""
        import zenoh

        return zenoh.handlers.Callback(self.callback, indirect=False)

    def callback(self, sample: Any) -> None:
        item = Received(str(sample.key_expr), sample.payload.to_bytes(), time.time(), _zenoh_seconds(sample.timestamp))
        if self.auth is not None:
            att = sample.attachment
            reason = self.auth.check(
                item.key, item.data, None if att is None else att.to_bytes(), item.t_recv, self._window
            )
            if reason is not None:
                with self._cond:
                    self.counters["received"] += 1
                    self.counters[f"dropped_{reason}"] += 1
                return
        self.put(item)

    def put(self, item: Received) -> bool:
        """Enqueue according to the policy. Returns False if the item was dropped."""
        with self._cond:
            self.counters["received"] += 1
            if self._closed:
                self.counters["dropped_closed"] += 1
                return False
            if len(self._items) >= self.maxsize:
                if self.policy == "drop_oldest":
                    self._items.popleft()
                    self.counters["dropped_oldest"] += 1
                else:
                    deadline = time.monotonic() + self.block_timeout
                    while len(self._items) >= self.maxsize and not self._closed:
                        left = deadline - time.monotonic()
                        if left <= 0:
                            break
                        self._cond.wait(left)
                    if self._closed:
                        self.counters["dropped_closed"] += 1
                        return False
                    if len(self._items) >= self.maxsize:
                        self.counters["dropped_full"] += 1
                        return False
            self._items.append(item)
            self._cond.notify_all()
            return True

    # consumer side
    def get(self, timeout: float | None = None) -> Received | None:
        """The next raw sample, or None after ``timeout`` s (None: wait until one arrives or close())."""
        with self._cond:
            deadline = None if timeout is None else time.monotonic() + timeout
            while not self._items:
                if self._closed:
                    return None
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._cond.wait(left)
            item = self._items.popleft()
            self._cond.notify_all()
            return item

    def get_message(self, timeout: float | None = None) -> tuple[Received, Any] | None:
        """The next sample that decodes, with its message; bad ones are counted as ``dropped_<reason>``
        and skipped. None on timeout or when closed and empty."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            item = self.get(left)
            if item is None:
                return None
            try:
                msg = item.decode()
            except ProtocolError as e:
                with self._cond:
                    self.counters[f"dropped_{e.reason}"] += 1
                continue
            with self._cond:
                self.counters["decoded"] += 1
            return item, msg

    def drain(self, max_items: int | None = None) -> list[Received]:
        """Everything queued now (up to ``max_items``), without waiting."""
        with self._cond:
            n = len(self._items) if max_items is None else min(max_items, len(self._items))
            out = [self._items.popleft() for _ in range(n)]
            self._cond.notify_all()
            return out

    def close(self) -> None:
        """Wake every waiter; later samples are dropped (``dropped_closed``)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def snapshot(self) -> dict[str, int]:
        with self._cond:
            return dict(self.counters)


def default_policy(key_expr: str) -> str:
    """The key table's receive policy for a concrete key or a wildcard of one kind (``hitl/<run>/feedback/*``);
    ``block`` for anything else (e.g. ``hitl/<run>/**``)."""
    parts = key_expr.split("/")
    if len(parts) >= 3 and parts[2] in KEYS:
        return KEYS[parts[2]].queue_policy
    return "block"
