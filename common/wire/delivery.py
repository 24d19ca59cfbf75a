"""What a service's code touches for each message it sends or receives: the `MessagePublisher` (encodes, which
validates, signs, sends), the `ResendRing` that keeps what was sent for a restarted receiver (`publish_kept`), the
bounded `Inbox` between a zenoh callback subscriber and the service's own thread (checks each sample's
authentication, queues it, decodes it), and the process's authentication default (common/wire/auth.py) that every
publisher and inbox uses. Sessions, routers and subscriber declarations: common/wire/transport.py.

At-least-once delivery across a restarted receiver (docs/faults.md): Step, Feedback, Ingest and EpisodeSummary are
published once, in order, on BLOCK keys; when a receiver that matters (learner, recorder) restarts, the publishers
re-send what they published in the last `window` seconds, and every receiver drops what it already has
(`duplicate`), so nobody double-counts.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from common.protocol import KEYS, ProtocolError, decode, parse_key

if TYPE_CHECKING:
    import zenoh

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


class Forward(Inbox):
    """An Inbox that queues nothing: each authentic sample goes to ``deliver`` at once, on zenoh's thread (for a
    consumer with its own event loop: ``deliver`` must not block, e.g. ``loop.call_soon_threadsafe``). The checks
    and counters are the Inbox's (``received``, ``dropped_<auth reason>``, ``dropped_closed``)."""

    def __init__(self, deliver: Callable[[Received], None], *, auth: Any = None):
        super().__init__(1, "drop_oldest", auth=auth)
        self.deliver = deliver

    def put(self, item: Received) -> bool:
        with self._cond:
            self.counters["received"] += 1
            if self._closed:
                self.counters["dropped_closed"] += 1
                return False
        self.deliver(item)
        return True


# -- sending ----------------------------------------------------------------------------------------------------------


class MessagePublisher:
    """Publishes protocol messages on one key: encodes (which validates), signs (with ``auth``, default the
    process's: :func:`set_default_auth`), counts, and closes cleanly.

    ``put`` accepts a message object or already-encoded bytes."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        *,
        congestion: str | None = None,
        express: bool = False,
        auth: Any = None,
    ):
        self.key = key
        self.message_type = parse_key(key).spec.message
        from common.wire.transport import declare_publisher

        self.publisher = declare_publisher(session, key, congestion=congestion, express=express)
        self.auth = auth if auth is not None else default_auth()
        self._lock = threading.Lock()  # counters go out in the order they were drawn
        self.sent = 0

    def put(self, message: Any) -> None:
        if isinstance(message, (bytes, bytearray, memoryview)):
            data = bytes(message)
        else:
            if not isinstance(message, self.message_type):
                raise TypeError(f"{self.key} carries {self.message_type.__name__}, not {type(message).__name__}")
            data = message.encode()
        if self.auth is None:
            self.publisher.put(data)
        else:
            with self._lock:
                self.publisher.put(data, attachment=self.auth.sign(self.key, data))
        self.sent += 1

    def wait_for_subscribers(self, timeout: float = 5.0) -> bool:
        from common.wire.transport import wait_for_matching

        return wait_for_matching(self.publisher, timeout)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.publisher.undeclare()

    def __enter__(self) -> MessagePublisher:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


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
