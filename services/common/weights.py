"""The weights follower: the newest Weights of an announced learner, loaded into one agent's policy (row 0).

The actor acts with it and the console shows Q and H with it (services/console/bridge.py): both adopt a Weights
message only if it decodes with the agent's own tensor names and shapes, belongs to this run, is stamped near its
arrival (`max_future`, `max_past`), comes from a learner incarnation announced by its ServiceStatus or liveliness
token, is not ahead of what the actor has sent (`limit`, the actor's) and is newer in (version, revision) than the
weights held (a new learner incarnation starts again from its own). Everything else is dropped and counted
(`weights_dropped_<reason>`, `weights_not_newer`).
"""

from __future__ import annotations

import time
from typing import Any, Protocol

from common.protocol import ProtocolError, ServiceStatus, Weights
from services.common.gate import first_time_logger

MAX_ANNOUNCED = 16  # learner incarnations remembered from their statuses (newest last)


class Announcements(Protocol):
    def known(self, incarnation: str) -> bool: ...


class WeightsFollower:
    """The newest acceptable weights, loaded into `agent`'s row 0 as they are offered (never older ones)."""

    def __init__(self, agent: Any, spec: dict[str, tuple[int, ...]], rt: Any):
        self.agent, self.spec, self.rt = agent, spec, rt
        self.version = 0
        self.revision: int | None = None  # of the weights held (None: the seed's, or a learner without revisions)
        self.limit: int | None = None  # no version above this (steps published + 1); None: any (a restart's wait)
        self.learner: str | None = None
        self.announced: list[str] = []  # learner incarnations announced by their ServiceStatus (newest last)
        self.watch: Announcements | None = None  # the learner's liveliness tokens (an IncarnationWatch)
        self._note = first_time_logger(rt.event, "weights")

    @property
    def progress(self) -> tuple[int, int]:
        return (self.version, -1 if self.revision is None else self.revision)

    def announce(self, status: ServiceStatus) -> None:
        """A learner's ServiceStatus: its incarnation may now send weights."""
        if status.incarnation and status.incarnation not in self.announced:
            self.announced = (self.announced + [status.incarnation])[-MAX_ANNOUNCED:]

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
