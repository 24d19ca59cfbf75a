"""What a subscriber checks on every decoded input before it reaches a model (docs/faults.md): the `InputGate` for
Step and Feedback (validation beyond the wire format, dedup by (incarnation, seq) or (teacher, seq), one warning
per reason), the `WeightsFollower` for Weights, and the `IncarnationWatch` of the liveliness tokens by which both
know a sender's incarnation announced.

The weights follower loads the newest Weights of an announced learner into one agent's policy (row 0). The actor
acts with it and the console shows Q and H with it (services/console/bridge.py): both adopt a Weights message only
if it decodes with the agent's own tensor names and shapes, belongs to this run, is stamped near its arrival
(`max_future`, `max_past`), comes from a learner incarnation announced by its ServiceStatus or liveliness token, is
not ahead of what the actor has sent (`limit`, the actor's) and is newer in (version, revision) than the weights
held (a new learner incarnation starts again from its own). Everything else is dropped and counted
(`weights_dropped_<reason>`, `weights_not_newer`).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from typing import Any
from collections.abc import Callable, Iterable

from common.protocol import Feedback, ProtocolError, ServiceStatus, Step, Weights, teacher_id_of

# -- rejected-input reasons beyond the decoders' (common.protocol.REASONS) ------------------------------------------

GATE_REASONS: dict[str, str] = {
    "future_timestamp": "t_action / t_reaction / t_published more than `max_future` s after arrival",
    "stale_timestamp": "t_action / t_reaction / t_published more than `max_past` s before arrival",
    "unknown_incarnation": "a Step (Weights) from an actor (learner) incarnation no ServiceStatus has announced",
    "retired_incarnation": "a Step from an actor incarnation that a newer one has replaced",
    "unknown_teacher": "Feedback from a teacher that neither the config nor a ServiceStatus names",
    "bad_seq": "a seq too far ahead: a step more than `max_seq_jump` beyond the next expected one, a feedback more "
    "than `max_feedback_jump` beyond its teacher's newest or one whose gap would leave more than "
    "`feedback_window` of its teacher's seqs outstanding (it would hide later real inputs)",
    "obs_shape": "Step.obs / next_obs length differs from the environment's observation size",
    "action_range": "Step.action outside the environment's action space",
}
DEDUP_REASON = "duplicate"  # already consumed (a re-sent input): dropped silently, counted apart

MAX_ANNOUNCED = 64  # incarnations / teachers remembered from statuses or tokens (bounded: they may be forged)
MAX_LEARNERS = 16  # learner incarnations a WeightsFollower remembers from their statuses (newest last)
MAX_FEEDBACK_JUMP = 1024  # a teacher's feedback seq at most this far beyond its newest admitted one
FEEDBACK_WINDOW = 4096  # skipped feedback seqs a teacher may have outstanding (awaited: they may come late)


class InputGate:
    """What a subscriber checks on every decoded Step and Feedback before it reaches a model.

    `admit_step` / `admit_feedback` return None (admitted: the dedup state moves on) or the reason of the
    rejection (`GATE_REASONS` or `duplicate`). Steps are accepted only from an actor incarnation a
    ServiceStatus announced (`on_status`); a new one retires the previous. Feedback only from teachers named
    in the config or announced. All state is plain JSON (`state()` / `load()`) for the learner's checkpoint.
    """

    def __init__(
        self,
        obs_dim: int,
        n_actions: int,
        *,
        teachers: Iterable[str] = (),
        max_future: float = 10.0,
        max_past: float = 600.0,
        max_seq_jump: int = 4096,
        max_feedback_jump: int = MAX_FEEDBACK_JUMP,
        feedback_window: int = FEEDBACK_WINDOW,
    ):
        self.obs_dim, self.n_actions = int(obs_dim), int(n_actions)
        self.max_future, self.max_past, self.max_seq_jump = float(max_future), float(max_past), int(max_seq_jump)
        self.max_feedback_jump, self.feedback_window = int(max_feedback_jump), int(feedback_window)
        self.configured_teachers = set(teachers)
        self.announced: collections.OrderedDict[str, None] = collections.OrderedDict()  # actor incarnations
        self.teachers: collections.OrderedDict[str, None] = collections.OrderedDict()  # announced teacher ids
        self.retired: collections.OrderedDict[str, None] = collections.OrderedDict()
        self.actor: str | None = None
        self.next_step: int | None = None  # next seq of self.actor (None: take whatever comes first)
        # Every teacher starts at seq 0 (a restarted one continues its seq; a new incarnation is a new teacher id),
        # so a forged seq far ahead is `bad_seq` from the start. Per teacher: the seq after its newest admitted one
        # and the seqs skipped below it that may still come (a jump never hides the real ones: see check_feedback).
        self.next_feedback: dict[str, int] = {}
        self.missing_feedback: dict[str, set[int]] = {}
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
        elif teacher := teacher_id_of(st.service):
            self._remember(self.teachers, teacher)

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
        """A seq below the teacher's newest is admitted once if it was skipped (it arrives late); one above it
        only within `max_feedback_jump`, and only while the seqs it skips fit in `feedback_window`. So a jump
        (a forged seq +4000, even signed with a stolen credential) is refused and counted instead of moving the
        window past the real teacher's next presses, and an admitted jump takes only its own seq from them."""
        if not self.teacher_known(fb.teacher_id):
            return "unknown_teacher"
        reason = self._time_reason(fb.t_reaction, t_recv)
        if reason:
            return reason
        nxt = self.next_feedback.get(fb.teacher_id, 0)
        if fb.seq < nxt:
            return None if fb.seq in self.missing_feedback.get(fb.teacher_id, ()) else DEDUP_REASON
        skipped = fb.seq - nxt
        if skipped > self.max_feedback_jump or (
            skipped and len(self.missing_feedback.get(fb.teacher_id, ())) + skipped > self.feedback_window
        ):
            return "bad_seq"
        return None

    def admit_feedback(self, fb: Feedback, t_recv: float) -> str | None:
        reason = self.check_feedback(fb, t_recv)
        if reason:
            return self._reject(reason)
        tid, nxt = fb.teacher_id, self.next_feedback.get(fb.teacher_id, 0)
        missing = self.missing_feedback.setdefault(tid, set())
        if fb.seq < nxt:
            missing.discard(fb.seq)
        else:
            missing.update(range(nxt, fb.seq))
            self.next_feedback[tid] = fb.seq + 1
        if not missing:
            del self.missing_feedback[tid]
        self.counters["feedback_admitted"] += 1
        return None

    def rejected(self) -> dict[str, int]:
        """Counts by reason (without `duplicate` and the admitted counts)."""
        return {k: v for k, v in self.counters.items() if k in GATE_REASONS}

    # -- checkpoint ------------------------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "announced": list(self.announced),
            "teachers": list(self.teachers),
            "retired": list(self.retired),
            "actor": self.actor,
            "next_step": self.next_step,
            "next_feedback": dict(self.next_feedback),
            "missing_feedback": {t: sorted(m) for t, m in self.missing_feedback.items()},
            "counters": dict(self.counters),
        }

    def load(self, state: dict[str, Any]) -> None:
        self.announced = collections.OrderedDict((k, None) for k in state["announced"])
        self.teachers = collections.OrderedDict((k, None) for k in state["teachers"])
        self.retired = collections.OrderedDict((k, None) for k in state["retired"])
        self.actor = state["actor"]
        self.next_step = state["next_step"]
        self.next_feedback = {str(k): int(v) for k, v in state["next_feedback"].items()}
        self.missing_feedback = {str(k): {int(x) for x in v} for k, v in state.get("missing_feedback", {}).items()}
        self.counters = collections.Counter({str(k): int(v) for k, v in state["counters"].items()})


def first_time_logger(emit: Callable[[str, int], None], what: str) -> Callable[[str, str], None]:
    """A callback `(reason, detail)` that emits one warning per reason (the counters say how many)."""
    seen: set[str] = set()

    def note(reason: str, detail: str = "") -> None:
        if reason in seen:
            return
        seen.add(reason)
        emit(f"rejected {what}: {reason}{' (' + detail + ')' if detail else ''}; further ones are only counted", 3)

    return note


# -- the weights' gate, and the incarnations announced by liveliness tokens --


class WeightsFollower:
    """The newest acceptable weights, loaded into `agent`'s row 0 as they are offered (never older ones)."""

    def __init__(self, agent: Any, spec: dict[str, tuple[int, ...]], rt: Any):
        self.agent, self.spec, self.rt = agent, spec, rt
        self.version = 0
        self.revision: int | None = None  # of the weights held (None: the seed's, or a learner without revisions)
        self.limit: int | None = None  # no version above this (steps published + 1); None: any (a restart's wait)
        self.learner: str | None = None
        self.announced: list[str] = []  # learner incarnations announced by their ServiceStatus (newest last)
        self.watch: IncarnationWatch | None = None  # the learner's liveliness tokens
        self._note = first_time_logger(rt.event, "weights")

    @property
    def progress(self) -> tuple[int, int]:
        return (self.version, -1 if self.revision is None else self.revision)

    def announce(self, status: ServiceStatus) -> None:
        """A learner's ServiceStatus: its incarnation may now send weights."""
        if status.incarnation and status.incarnation not in self.announced:
            self.announced = (self.announced + [status.incarnation])[-MAX_LEARNERS:]

    def on_status(self, inbox: Any) -> None:
        """Announce the learners whose statuses wait in `inbox` (undecodable ones are counted)."""
        for it in inbox.drain():
            try:
                st = it.decode()
            except ProtocolError:
                self.rt.counters["rejected_status"] += 1
                continue
            if isinstance(st, ServiceStatus):
                self.announce(st)

    def known(self, incarnation: str) -> bool:
        return (
            incarnation == self.learner
            or incarnation in self.announced
            or (self.watch is not None and self.watch.known(incarnation))
        )

    def _reject(self, reason: str) -> None:
        self.rt.counters[f"weights_dropped_{reason}"] += 1
        self._note(reason, "")

    def _why_not(self, w: Weights, t_recv: float, status: Any) -> str | None:
        """Why `w` may not be adopted (None: it may)."""
        cfg = self.rt.config
        if w.run != cfg.run:
            return "wrong_run"
        if w.t_published > t_recv + cfg.max_future:
            return "future_timestamp"
        if w.t_published < t_recv - cfg.max_past:
            return "stale_timestamp"
        if not self.known(w.incarnation) and status is not None:
            self.on_status(status)  # its announcement may be waiting in the status queue
        if not self.known(w.incarnation):
            return "unknown_incarnation"
        if self.limit is not None and w.version > self.limit:
            return "version_ahead"  # a learner cannot have learned steps this actor never sent
        return None

    def offer(self, data: bytes, t_recv: float, status: Any = None) -> bool:
        """One Weights message as received; True if adopted. `status`: an inbox of learner statuses to read when
        the sender is not yet known."""
        try:
            w = Weights.decode(data, expected=self.spec)
        except ProtocolError as e:
            self._reject(e.reason)
            return False
        reason = self._why_not(w, t_recv, status)
        if reason is not None:
            self._reject(reason)
            return False
        if w.incarnation == self.learner and w.progress <= self.progress:
            self.rt.counters["weights_not_newer"] += 1
            return False
        if w.incarnation != self.learner and self.learner is not None:
            self.rt.counters["learner_restarts"] += 1
        self.agent.load_policy_weights(w.tensors, 0)
        self.learner, self.version, self.revision = w.incarnation, int(w.version), w.revision
        self.rt.counters["weights_adopted"] += 1
        self.rt.samples["adopt_latency_s"].append(time.time() - w.t_published)
        return True

    def adopt(self, inbox: Any, timeout: float | None = None, status: Any = None) -> bool:
        """Offer every Weights queued in `inbox` (waiting up to `timeout` s for one if given). True if any was
        adopted."""
        item = inbox.get(timeout) if timeout is not None else None
        items = ([item] if item is not None else []) + inbox.drain()
        adopted = False
        for it in items:
            adopted = self.offer(it.data, it.t_recv, status) or adopted
        return adopted


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
        self._sub = session.liveliness().declare_subscriber(
            f"{alive_key(run, service)}/*", self._on_sample, history=True
        )

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
