"""The bridge between the run (Zenoh) and the pages (WebSocket), living on the console's asyncio loop.

From the run to every page: each Step as a scene (where the agent is), the agent's current Q and H per
action and alpha_h (computed here from the learner's newest Weights, as the actor would), each episode's
return (the learning curve), each Credit (which steps a feedback was credited to), the face read from a
person's webcam and the feedback it became, and whether the run is paused or over.

From a page to the run: its person's feedback (stamped with the system time of the press and listing the
steps their screen showed), the paint time of each step (`Shown`), run controls (`Control`) and webcam frames
(`foxglove.CompressedImage`, frame_id = the person's teacher id, for the perception service). Each person
is a teacher: their ServiceStatus (`teacher.<id>`) announces them to the learner and carries their count of
feedback at the end.
"""

from __future__ import annotations

import asyncio
import base64
import collections
import contextlib
import dataclasses
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from common.envs import make_env, n_actions, obs_shape
from common.envs.scene import SceneTracker, static_scene
from common.protocol import (
    TEACHER_PREFIX,
    KEYS,
    CompressedImage,
    Control,
    Credit,
    EpisodeSummary,
    ExpressionPrediction,
    Feedback,
    ProtocolError,
    ServiceStatus,
    Step,
    Time,
    camera_key,
    control_key,
    decode,
    episode_key,
    perception_key,
    status_key,
    step_key,
    weights_key,
)
from common.wire.delivery import Received
from services.console.config import ConsoleConfig
from services.console.people import Ledger, PageInputs, Person, RateLimit
from services.console.prefs import PrefsFeed
from services.common.gate import WeightsFollower

TEACHER = TEACHER_PREFIX


class Hub(PageInputs):
    """Run state for the pages, and the publishers that carry the people's input into the run."""

    def __init__(self, config: ConsoleConfig, rt: Any, session: Any, loop: asyncio.AbstractEventLoop):
        from common.agents import make_agent  # torch: only a live console needs it, not `--replay`
        from common.wire.transport import MessagePublisher

        self.config, self.rt, self.session, self.loop = config, rt, session, loop
        self.span = config.span  # (parsed from the delay spec once, not on every press)
        env, _ = make_env(config.env, config.layout)
        self.obs_dim, self.n_actions = int(np.prod(obs_shape(env))), n_actions(env)
        env.close()
        self.agent = make_agent([config.agent], obs_shape(env), self.n_actions, [config.seed])
        self.spec = {k: tuple(v.shape) for k, v in self.agent.policy_weights(0).items()}
        self.scene_static = static_scene(config.env, config.layout)
        self.tracker = SceneTracker(config.env, config.layout)
        self.people: dict[str, Person] = {}
        self.ledger = Ledger(config.state_file)
        self.last_step: dict | None = None
        self.recent: collections.OrderedDict[tuple[str, int], float] = collections.OrderedDict()  # -> t_action
        self.obs: np.ndarray | None = None
        self.curve: list[dict] = []
        self.trail: collections.deque = collections.deque(maxlen=64)
        self.paused, self.rate = False, config.rate
        self.awaiting_start = config.start_on_first_page  # until the first step or a person's own control
        self.start_sent_at = 0.0
        self.actor_stopped = self.learner_stopped = False
        # the actor's follower and checks: a press's H update (a new revision) shows before the next step
        self.weights = WeightsFollower(self.agent, self.spec, rt)
        self.prefs = PrefsFeed(self.agent, self.weights, loop, self.broadcast)
        self.control_seq = 0
        self.pub = lambda key: MessagePublisher(session, key)  # noqa: E731
        self.control_pub = MessagePublisher(session, control_key(config.run))
        self.camera_pub = MessagePublisher(session, camera_key(config.run, config.camera)) if config.camera else None
        self.pubs: dict[str, Any] = {}
        self.subs = contextlib.ExitStack()

    # -- Zenoh -> loop ---------------------------------------------------------------------------------------------
    def subscribe(self) -> None:
        """Every key the pages need, through the project's one subscription helper (signatures checked there:
        a forgery never reaches a page or a person's status), each sample handed to the loop."""
        from common.wire.transport import subscriptions
        from services.common.gate import IncarnationWatch

        run = self.config.run
        keys = [
            step_key(run),
            episode_key(run),
            weights_key(run),
            KEYS["credit"].wildcard(run),
            KEYS["status"].wildcard(run),
            KEYS["control"].wildcard(run),
        ]
        if self.config.camera:  # (feedback: only a face's is shown; without a camera it was the pages' own, back)
            keys += [perception_key(run, self.config.camera), KEYS["feedback"].wildcard(run)]
        if self.scene_static is None:  # the actor's picture of an env we cannot draw (services/actor/render.py)
            keys.append(camera_key(run, "env"))
        self.weights.watch = self.subs.enter_context(contextlib.closing(IncarnationWatch(self.session, run, "learner")))
        self.subs.enter_context(subscriptions(self.session, keys, auth=self.rt.auth, deliver=self._on_sample))

    def _on_sample(self, item: Received) -> None:  # a zenoh thread: hand the bytes to the loop
        self.loop.call_soon_threadsafe(self.on_message, item.key, item.data, item.t_recv)

    def on_message(self, key: str, data: bytes, t_recv: float) -> None:
        if key == weights_key(self.config.run):
            if self.weights.offer(data, t_recv):
                self.prefs.weights_adopted(len(self.people))
            return
        try:
            msg = decode(key, data)
        except ProtocolError as e:
            self.rt.counters[f"run_rejected_{e.reason}"] += 1
            return
        if isinstance(msg, CompressedImage):
            if msg.frame_id.isdigit() and key.endswith("/camera/env"):
                self.broadcast(
                    {
                        "type": "frame",
                        "seq": int(msg.frame_id),
                        "format": msg.format,
                        "data": base64.b64encode(msg.data).decode("ascii"),
                    }
                )
            return
        handlers: dict[type, Callable[[Any, float], None]] = {
            Step: self._step,
            EpisodeSummary: self._episode,
            Credit: self._credit,
            ServiceStatus: self._status,
            Feedback: self._feedback,
            ExpressionPrediction: self._face,
            Control: self._control,
        }
        handler = handlers.get(type(msg))
        if handler is not None and getattr(msg, "run", self.config.run) == self.config.run:
            handler(msg, t_recv)

    def broadcast(self, payload: dict) -> None:
        for person in list(self.people.values()):
            person.send(payload)

    def _step(self, step: Step, t_recv: float) -> None:
        self.awaiting_start = False
        scene = self.tracker.after(step.t_in_episode, step.action, step.next_obs)
        self.obs = self.prefs.obs = np.asarray(step.next_obs, np.float32)
        self.recent[(step.incarnation, step.seq)] = step.t_action
        while len(self.recent) > 256:
            self.recent.popitem(last=False)
        self.agent.steps[0] = step.seq + 1  # alpha_h's schedule at the next action
        self.last_step = {
            "type": "step",
            "actor": step.incarnation,
            "seq": step.seq,
            "episode": step.episode,
            "t_in_episode": step.t_in_episode,
            "action": step.action,
            "reward": step.reward,
            "terminated": step.terminated,
            "truncated": step.truncated,
            "t_action": step.t_action,
            "t_recv": t_recv,
            "next_obs": [round(float(x), 4) for x in step.next_obs[:32]],
            "scene": scene,
            "weights_version": step.weights_version,
            "info": dict(step.info),
        }
        self.broadcast(self.last_step)
        self.prefs.send_now(len(self.people))

    def preferences(self) -> dict:
        self.prefs.obs = self.obs
        return self.prefs.current()

    def _episode(self, ep: EpisodeSummary, t_recv: float) -> None:
        point = {
            "episode": ep.episode,
            "return": ep.return_,
            "steps": ep.steps,
            "feedback_received": ep.feedback_received,
            "feedback_credited": ep.feedback_credited,
        }
        self.curve.append(point)
        self.broadcast({"type": "episode", **point})

    def _credit(self, c: Credit, t_recv: float) -> None:
        item = {
            "type": "credit",
            "teacher_id": c.teacher_id,
            "seq": c.seq,
            "value": c.value,
            "status": c.status,
            "t_reaction": c.t_reaction,
            "t_credited": c.t_credited,
            "t_recv": t_recv,
            "actor": c.actor,
            "steps": [{"seq": s.seq, "weight": s.weight} for s in c.steps],
            "lost_mass": c.lost_mass,
            "delay": dataclasses.asdict(c.delay) if c.delay is not None else None,
        }
        self.trail.append(item)
        self.rt.samples["press_to_credited_s"].append(c.t_credited - c.t_reaction)
        self.broadcast(item)

    def _feedback(self, fb: Feedback, t_recv: float) -> None:
        if fb.source == "face":  # a webcam's feedback (from the perception service): show whose and when
            self.broadcast(
                {
                    "type": "face_feedback",
                    "teacher_id": fb.teacher_id,
                    "seq": fb.seq,
                    "value": fb.value,
                    "t_reaction": fb.t_reaction,
                    "t_recv": t_recv,
                }
            )

    def _face(self, p: ExpressionPrediction, t_recv: float) -> None:
        self.rt.samples["frame_to_expression_s"].append(t_recv - p.t_capture)
        self.broadcast(
            {
                "type": "face",
                "label": p.label,
                "confidence": round(p.confidence, 3),
                "box": None if p.box is None else [p.box.x, p.box.y, p.box.w, p.box.h],
                "t_capture": p.t_capture,
                "t_recv": t_recv,
            }
        )

    def _control(self, c: Control, t_recv: float) -> None:
        if c.command in ("pause", "resume"):
            self.paused = c.command == "pause"
        elif c.command == "pace" and c.rate is not None:  # (Control's check: a pace carries a rate)
            self.rate = float(c.rate)
        self.broadcast(self.control_state(by=c.source))

    def control_state(self, by: str | None = None) -> dict:
        return {"type": "control", "paused": self.paused, "rate": self.rate, "ended": self.actor_stopped, "by": by}

    def _status(self, st: ServiceStatus, t_recv: float) -> None:
        if st.service == "learner":
            self.weights.announce(st)
        if st.state != "stopped":
            return
        if st.service == "actor" and not self.actor_stopped:
            self.actor_stopped = True
            self.broadcast(self.control_state())
            for person in self.people.values():  # their counts are final: the learner may end
                self.person_status(person, "stopped")
            self.rt.publish_status("stopped")  # the console's own identity never sends feedback
        elif st.service == "learner":
            self.learner_stopped = True

    # -- pages -> run ------------------------------------------------------------------------------------------
    def person_status(self, person: Person, state: str) -> None:
        service = f"{TEACHER_PREFIX}{person.teacher_id}"
        self._publisher(status_key(self.config.run, service)).put(
            ServiceStatus(
                run=self.config.run,
                service=service,
                pid=os.getpid(),
                state=state,
                t=time.time(),
                counters={**self.ledger.counters(person.teacher_id), "frames_published": person.frames_sent},
                incarnation=person.incarnation,
            )
        )

    def frame(self, person: Person, t_capture: float, jpeg: bytes) -> None:
        if self.camera_pub is None:
            self.rt.counters["page_rejected_no_camera"] += 1
            return
        if self.actor_stopped:  # the run is over: the perception service may finish
            self.rt.counters["frames_after_end"] += 1
            return
        self.camera_pub.put(
            CompressedImage(
                timestamp=Time.from_seconds(t_capture), frame_id=person.teacher_id, data=jpeg, format="jpeg"
            )
        )
        person.frames_sent += 1
        self.rt.counters["frames_published"] += 1

    def join(self, name: str | None, page_id: str | None, send) -> Person:
        """A page opens: its teacher id is `<prefix>-<name>`, the id this page had before (a reload, or a
        reconnect after a console restart), or `<prefix>-<n>`; a name already at the console gets a suffix."""
        ledger, c = self.ledger, self.config
        ledger.joined += 1
        before = ledger.page_teacher(page_id)
        base = f"{c.teacher_prefix}-{name}" if name else before or f"{c.teacher_prefix}-{ledger.joined}"
        tid = base if base not in self.people else f"{base}-{ledger.joined}"
        ledger.bind(page_id, tid)
        ledger.save()
        person = Person(
            tid,
            RateLimit(c.max_press_rate, 2 * c.max_press_rate),
            RateLimit(c.max_frame_rate),
            incarnation=f"{TEACHER}{tid}-{os.getpid()}-{ledger.joined}",
            send=send,
            controls=RateLimit(c.max_control_rate, 5.0),
            page_id=page_id,
        )
        self.people[tid] = person
        self.rt.counters["people_joined"] += 1
        try:
            self.person_status(person, "ready")
        except Exception:
            self.people.pop(tid, None)
            raise
        return person

    def announce(self) -> None:
        """Each person's status again (a learner that started late, or restarted, learns who teaches)."""
        state = "stopped" if self.actor_stopped else "ready"
        for person in list(self.people.values()):
            try:
                self.person_status(person, state)
            except Exception as exc:  # one person's status must not stop the console (counted, said once)
                self.rt.counters["status_failed"] += 1
                self.rt.event(f"status of {person.teacher_id} not published: {exc!r}", 3)

    def leave(self, person: Person) -> None:
        self.people.pop(person.teacher_id, None)
        self.person_status(person, "stopped")

    def control(self, person: Person, m: dict) -> None:
        self.awaiting_start = False  # a person took charge
        self._publish_control(person.teacher_id, m["command"], m["rate"])

    def _publish_control(self, source: str, command: str, rate: float | None) -> None:
        self.control_pub.put(
            Control(run=self.config.run, source=source, seq=self.control_seq, t=time.time(), command=command, rate=rate)
        )
        self.control_seq += 1

    def start_when_watched(self) -> None:
        """Resume the actor waiting for the first page once that page is ready: open, and its clock estimated (a
        step painted before that would not be shown to the person). Again every 0.5 s until the first step arrives
        (the actor may subscribe to controls late, and a control is not kept for late subscribers)."""
        ready = [p for p in self.people.values() if p.clock_ready]
        if not self.awaiting_start or not ready or time.monotonic() - self.start_sent_at < 0.5:
            return
        self._publish_control(ready[0].teacher_id, "resume", None)
        self.start_sent_at = time.monotonic()

    def hello(self, person: Person) -> dict:
        return {
            "type": "hello",
            "teacher_id": person.teacher_id,
            "run": self.config.run,
            "env": self.config.env,
            "layout": self.config.layout,
            "algo": self.config.algo,
            "scene": self.scene_static,
            "n_actions": self.n_actions,
            "rate": self.rate,
            "paused": self.paused,
            "episodes": self.config.episodes,
            "camera": self.config.camera is not None,
            "span": self.span,
            "curve": self.curve,
            "trail": list(self.trail),
            "ended": self.actor_stopped,
            "screen_delay": self.config.screen_delay,
        }

    def close(self) -> None:
        self.subs.close()
        for pub in [self.control_pub, *self.pubs.values()] + ([self.camera_pub] if self.camera_pub else []):
            pub.close()
