"""Fault tolerance shared by the services (docs/faults.md): validation of decoded inputs beyond the wire
format (`InputGate`), at-least-once delivery across a restarted receiver (`ResendRing` + `AliveWatch`), and
atomic state files.

Delivery model: Step, Feedback, Ingest and EpisodeSummary are published once, in order, on BLOCK keys. When
a receiver that matters (learner, recorder) restarts, the publishers re-send what they published in the
last `resend_window` seconds; every receiver is idempotent: it keys inputs by (actor incarnation, seq) or
(teacher, seq) and drops what it already has (`duplicate`). So a restarted learner or recorder gets back
what was in flight while it was down (or not yet flushed to the log), and nobody double-counts.
"""
from __future__ import annotations

import collections
import json
import math
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from common.protocol import Feedback, ProtocolError, ServiceStatus, Step, teacher_id_of

# -- rejected-input reasons beyond the decoders' (common.protocol.REASONS) ------------------------------------------

GATE_REASONS: dict[str, str] = {
    "future_timestamp": "t_action / t_reaction / t_published more than `max_future` s after arrival",
    "stale_timestamp": "t_action / t_reaction / t_published more than `max_past` s before arrival",
    "unknown_incarnation": "a Step (Weights) from an actor (learner) incarnation no ServiceStatus has announced",
    "retired_incarnation": "a Step from an actor incarnation that a newer one has replaced",
    "unknown_teacher": "Feedback from a teacher that neither the config nor a ServiceStatus names",
    "bad_seq": "a seq more than `max_seq_jump` ahead of the next expected one (would hide later real inputs)",
    "obs_shape": "Step.obs / next_obs length differs from the environment's observation size",
    "action_range": "Step.action outside the environment's action space",
}
DEDUP_REASON = "duplicate"  # already consumed (a re-sent input): dropped silently, counted apart

MAX_ANNOUNCED = 64  # incarnations / teachers remembered from statuses (bounded: statuses may be forged)


class InputGate:
    """What a subscriber checks on every decoded Step and Feedback before it reaches a model.

    `admit_step` / `admit_feedback` return None (admitted: the dedup state moves on) or the reason of the
    rejection (`GATE_REASONS` or `duplicate`). Steps are accepted only from an actor incarnation a
    ServiceStatus announced (`on_status`); a new one retires the previous. Feedback only from teachers named
    in the config or announced. All state is plain JSON (`state()` / `load()`) for the learner's checkpoint.
    """

    def __init__(self, obs_dim: int, n_actions: int, *, teachers: Iterable[str] = (), max_future: float = 10.0,
                 max_past: float = 600.0, max_seq_jump: int = 4096):
        self.obs_dim, self.n_actions = int(obs_dim), int(n_actions)
        self.max_future, self.max_past, self.max_seq_jump = float(max_future), float(max_past), int(max_seq_jump)
        self.configured_teachers = set(teachers)
        self.announced: collections.OrderedDict[str, None] = collections.OrderedDict()  # actor incarnations
        self.teachers: collections.OrderedDict[str, None] = collections.OrderedDict()  # announced teacher ids
        self.retired: collections.OrderedDict[str, None] = collections.OrderedDict()
        self.actor: str | None = None
        self.next_step: int | None = None  # next seq of self.actor (None: take whatever comes first)
        # Configured teachers start with the run at seq 0 (a restarted one continues its seq), so a forged seq far
        # ahead is `bad_seq` from the start; an announced teacher may be joined mid-stream.
        self.next_feedback: dict[str, int] = {t: 0 for t in self.configured_teachers}
        self.counters: collections.Counter[str] = collections.Counter()

    # -- announcements -------------------------------------------------------------------------------------------
    @staticmethod
    def _remember(d: collections.OrderedDict, key: str) -> None:
        d[key] = None
        d.move_to_end(key)
        while len(d) > MAX_ANNOUNCED:
            d.popitem(last=False)

    def on_status(self, st: ServiceStatus) -> None:
        if st.service == "actor" and st.incarnation and st.incarnation not in self.retired:
            self._remember(self.announced, st.incarnation)
        elif teacher_id_of(st.service):
            self._remember(self.teachers, teacher_id_of(st.service))

    def announce(self, incarnation: str) -> None:
        """An actor incarnation seen alive (its liveliness token, see `IncarnationWatch`)."""
        if incarnation not in self.retired and incarnation != self.actor:
            self._remember(self.announced, incarnation)

    def teacher_known(self, teacher_id: str) -> bool:
        return teacher_id in self.configured_teachers or teacher_id in self.teachers

    # -- checks ----------------------------------------------------------------------------------------------------
    def _time_reason(self, t: float, t_recv: float) -> str | None:
        if not math.isfinite(t):
            return "stale_timestamp"
        if t > t_recv + self.max_future:
            return "future_timestamp"
        if t < t_recv - self.max_past:
            return "stale_timestamp"
        return None

    def _reject(self, reason: str) -> str:
        self.counters[reason] += 1
        return reason

    def check_step(self, step: Step, t_recv: float) -> str | None:
        """Reason to reject (no state change), or None."""
        if len(step.obs) != self.obs_dim or len(step.next_obs) != self.obs_dim:
            return "obs_shape"
        if not 0 <= step.action < self.n_actions:
            return "action_range"
        reason = self._time_reason(step.t_action, t_recv)
        if reason:
            return reason
        if step.incarnation in self.retired:
            return "retired_incarnation"
        if step.incarnation == self.actor:
            if self.next_step is not None:
                if step.seq < self.next_step:
                    return DEDUP_REASON
                if step.seq > self.next_step + self.max_seq_jump:
                    return "bad_seq"
            return None
        if step.incarnation not in self.announced:
            return "unknown_incarnation"
        if self.actor is not None and step.seq > self.max_seq_jump:
            return "bad_seq"  # a restarted actor starts at 0
        return None

    def admit_step(self, step: Step, t_recv: float) -> str | None:
        reason = self.check_step(step, t_recv)
        if reason:
            return self._reject(reason)
        if step.incarnation != self.actor:
            if self.actor is not None:
                self._remember(self.retired, self.actor)
                self.announced.pop(self.actor, None)
            self.actor = step.incarnation
        self.next_step = step.seq + 1
        self.counters["steps_admitted"] += 1
        return None

    def check_feedback(self, fb: Feedback, t_recv: float) -> str | None:
        if not self.teacher_known(fb.teacher_id):
            return "unknown_teacher"
        reason = self._time_reason(fb.t_reaction, t_recv)
        if reason:
            return reason
        nxt = self.next_feedback.get(fb.teacher_id)
        if nxt is not None:
            if fb.seq < nxt:
                return DEDUP_REASON
            if fb.seq > nxt + self.max_seq_jump:
                return "bad_seq"
        return None

    def admit_feedback(self, fb: Feedback, t_recv: float) -> str | None:
        reason = self.check_feedback(fb, t_recv)
        if reason:
            return self._reject(reason)
        self.next_feedback[fb.teacher_id] = fb.seq + 1
        self.counters["feedback_admitted"] += 1
        return None

    def rejected(self) -> dict[str, int]:
        """Counts by reason (without `duplicate` and the admitted counts)."""
        return {k: v for k, v in self.counters.items() if k in GATE_REASONS}

    # -- checkpoint ------------------------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"announced": list(self.announced), "teachers": list(self.teachers), "retired": list(self.retired),
                "actor": self.actor, "next_step": self.next_step, "next_feedback": dict(self.next_feedback),
                "counters": dict(self.counters)}

    def load(self, state: dict[str, Any]) -> None:
        self.announced = collections.OrderedDict((k, None) for k in state["announced"])
        self.teachers = collections.OrderedDict((k, None) for k in state["teachers"])
        self.retired = collections.OrderedDict((k, None) for k in state["retired"])
        self.actor = state["actor"]
        self.next_step = state["next_step"]
        self.next_feedback = {str(k): int(v) for k, v in state["next_feedback"].items()}
        self.counters = collections.Counter({str(k): int(v) for k, v in state["counters"].items()})


# -- re-sending to a restarted receiver -------------------------------------------------------------------------------

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
            items = items[len(items) - min(max(last, 0), len(items)):]
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


class IncarnationWatch:
    """The incarnations of one service that have held their liveliness token
    `hitl/<run>/alive/<service>/<incarnation>` (declared by `ServiceRuntime.ready()` before the service
    publishes anything). With history, a watcher started late still learns the current one, and a token is
    delivered before anything the same process publishes after declaring it. `take()`: new ones since the
    last call."""

    def __init__(self, session: Any, run: str, service: str):
        from services.common.runtime import alive_key

        self._lock = threading.Lock()
        self.seen: collections.OrderedDict[str, None] = collections.OrderedDict()
        self._new: list[str] = []
        self._sub = session.liveliness().declare_subscriber(f"{alive_key(run, service)}/*", self._on_sample,
                                                            history=True)

    def _on_sample(self, sample: Any) -> None:
        import zenoh

        if sample.kind != zenoh.SampleKind.PUT:
            return
        inc = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if inc not in self.seen:
                self._new.append(inc)
            self.seen[inc] = None
            while len(self.seen) > MAX_ANNOUNCED:
                self.seen.popitem(last=False)

    def known(self, incarnation: str) -> bool:
        with self._lock:
            return incarnation in self.seen

    def take(self) -> list[str]:
        with self._lock:
            out, self._new = self._new, []
        return out

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


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

    def before_exit(self, ring: "ResendRing", timeout: float, say: Callable[[str], None] | None = None) -> None:
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


# -- state files --------------------------------------------------------------------------------------------------------

def decoded_statuses(inbox: Any, counters: dict) -> Iterable[ServiceStatus]:
    """The statuses waiting in `inbox`, decoded; one that does not decode is counted as
    `rejected_status_<reason>` and dropped."""
    for item in inbox.drain():
        try:
            yield item.decode()
        except ProtocolError as e:
            counters[f"rejected_status_{e.reason}"] += 1


def atomic_write(path: str | os.PathLike, data: bytes) -> None:
    """Write to a temporary file beside `path`, then `os.replace`: readers see the old or the new file whole,
    also after a SIGKILL in the middle (the temporary file is left behind and overwritten next time)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
    os.replace(tmp, path)


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    atomic_write(path, json.dumps(obj, sort_keys=True).encode())


def read_json(path: str | os.PathLike) -> Any | None:
    """The JSON object in `path`, or None if there is none (a damaged file raises: never silently reset)."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return None


def first_time_logger(emit: Callable[[str, int], None], what: str) -> Callable[[str, str], None]:
    """A callback `(reason, detail)` that emits one warning per reason (the counters say how many)."""
    seen: set[str] = set()

    def note(reason: str, detail: str = "") -> None:
        if reason in seen:
            return
        seen.add(reason)
        emit(f"rejected {what}: {reason}{' (' + detail + ')' if detail else ''}; further ones are only counted", 3)

    return note
