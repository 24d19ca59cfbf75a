"""Key expressions: which message type travels on which key, and how it is carried.

Every key is ``hitl/<run>/<kind>[/<name>]``. :data:`KEYS` is the single table; the recorder subscribes
to ``hitl/<run>/**`` and uses :func:`parse_key` / :func:`decode` to type what it receives.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from typing import Any

from ._media import CompressedImage, ExpressionPrediction, Log, ObserverReaction
from ._fields import NAME_PATTERN
from ._messages import EpisodeSummary, Feedback, Ingest, RunConfig, ServiceStatus, Step
from ._console import Control, Credit, Shown
from ._foxglove import SceneUpdate
from ._observe import Request, WeightsSnapshot
from ._spec import ProtocolError
from ._weights import Weights

ROOT = "hitl"
_NAME_RE = re.compile(NAME_PATTERN[:-1] + r"\Z")


@dataclasses.dataclass(frozen=True)
class KeySpec:
    """One row of the key table."""

    kind: str  # the third chunk: "step", "feedback", ...
    message: type[Any]  # the message class (a Message, or a FoxgloveProto for Foxglove's own schemas)
    param: str | None  # name of the fourth chunk, if any ("teacher_id", "service", "camera")
    congestion: str  # "block" (never dropped by Zenoh under load) or "drop"
    queue_policy: str  # default receive policy: "block" or "drop_oldest"
    doc: str
    logged: bool = True  # False: the recorder leaves it out of the log (counted), e.g. the actor's every-step weights

    def pattern(self) -> str:
        tail = f"/<{self.param}>" if self.param else ""
        return f"{ROOT}/<run>/{self.kind}{tail}"

    def key(self, run: str, name: str | None = None) -> str:
        validate_name(run, "run")
        if self.param:
            if name is None:
                raise ProtocolError("bad_value", f"{self.kind} key needs a {self.param}")
            validate_name(name, self.param)
            return f"{ROOT}/{run}/{self.kind}/{name}"
        if name is not None:
            raise ProtocolError("bad_value", f"{self.kind} key takes no name")
        return f"{ROOT}/{run}/{self.kind}"

    def wildcard(self, run: str) -> str:
        """Key expression that matches every key of this kind in the run."""
        validate_name(run, "run")
        return f"{ROOT}/{run}/{self.kind}/*" if self.param else f"{ROOT}/{run}/{self.kind}"


KEYS: dict[str, KeySpec] = {
    k.kind: k
    for k in [
        KeySpec("config", RunConfig, None, "block", "block", "Run configuration; the first record of every log."),
        KeySpec("step", Step, None, "block", "block", "Every environment step, from the actor."),
        KeySpec("feedback", Feedback, "teacher_id", "block", "block", "Binary feedback, one key per teacher."),
        KeySpec(
            "weights",
            Weights,
            None,
            "block",
            "block",
            "Network weights for the actor, from the learner (after almost every step in lockstep). An actor wants "
            "only the newest: receive with drop_oldest, maxsize 1. Not logged: the log has `snapshot`.",
            logged=False,
        ),
        KeySpec(
            "snapshot",
            WeightsSnapshot,
            None,
            "block",
            "block",
            "The learner's weights at a bounded rate, for logs and viewers: per-tensor numbers and the raw weights.",
        ),
        KeySpec(
            "request", Request, None, "drop", "drop_oldest", "Ask a service for something now (a weights snapshot)."
        ),
        KeySpec(
            "scene",
            SceneUpdate,
            "part",
            "block",
            "block",
            "The environment drawn for Foxglove's 3D panel (foxglove.SceneUpdate, protobuf): `layout` once per "
            "episode, `agent` per step, `feedback` per resolved feedback. Made by the recorder and the Foxglove "
            "bridge from steps and credits (common/logs/scene.py).",
        ),
        KeySpec("episode", EpisodeSummary, None, "block", "block", "End-of-episode summary, from the learner."),
        KeySpec(
            "ingest",
            Ingest,
            None,
            "block",
            "block",
            "The learner's input order (what `replay retrain` feeds a fresh learner), from the learner.",
        ),
        KeySpec("status", ServiceStatus, "service", "drop", "drop_oldest", "Service liveness and counters."),
        KeySpec(
            "log",
            Log,
            "name",
            "block",
            "block",
            "Events for humans (foxglove.Log): supervision, restores, first rejection of each reason.",
        ),
        KeySpec("camera", CompressedImage, "camera", "drop", "drop_oldest", "Camera frames (JPEG)."),
        KeySpec(
            "perception", ExpressionPrediction, "camera", "drop", "drop_oldest", "Expression read from each frame."
        ),
        KeySpec(
            "reaction",
            ObserverReaction,
            "teacher_id",
            "block",
            "block",
            "Diagnostics of a video-backed observer: each reaction it showed the camera (never learned from).",
        ),
        KeySpec(
            "shown",
            Shown,
            "screen",
            "block",
            "block",
            "A step painted on a person's console page, with its screen time (from the console).",
        ),
        KeySpec("control", Control, None, "block", "block", "Pause, resume, pace, end: a person's run controls."),
        KeySpec(
            "credit",
            Credit,
            "teacher_id",
            "block",
            "block",
            "What the learner did with each feedback: the steps credited and their weights.",
        ),
    ]
}

MESSAGE_TYPES: tuple[type, ...] = tuple(k.message for k in KEYS.values())


def validate_name(name: Any, what: str = "run") -> str:
    """Check a run / teacher / service / camera name that becomes a key chunk; return it."""
    if not isinstance(name, str):
        raise ProtocolError("wrong_type", f"{what}: expected string, got {type(name).__name__}")
    if not _NAME_RE.match(name):
        raise ProtocolError("bad_value", f"{what}: {name[:40]!r} does not match {NAME_PATTERN}")
    return name


def run_prefix(run: str) -> str:
    """``hitl/<run>/**``: everything in a run (what a recorder subscribes to)."""
    validate_name(run, "run")
    return f"{ROOT}/{run}/**"


def step_key(run: str) -> str:
    return KEYS["step"].key(run)


def feedback_key(run: str, teacher_id: str) -> str:
    return KEYS["feedback"].key(run, teacher_id)


def feedback_wildcard(run: str) -> str:
    """``hitl/<run>/feedback/*``: every teacher's feedback (what the learner subscribes to)."""
    return KEYS["feedback"].wildcard(run)


def weights_key(run: str) -> str:
    return KEYS["weights"].key(run)


def episode_key(run: str) -> str:
    return KEYS["episode"].key(run)


def status_key(run: str, service: str) -> str:
    return KEYS["status"].key(run, service)


def log_key(run: str, name: str) -> str:
    return KEYS["log"].key(run, name)


def camera_key(run: str, camera: str) -> str:
    return KEYS["camera"].key(run, camera)


def perception_key(run: str, camera: str) -> str:
    return KEYS["perception"].key(run, camera)


def reaction_key(run: str, teacher_id: str) -> str:
    return KEYS["reaction"].key(run, teacher_id)


def shown_key(run: str, screen: str) -> str:
    return KEYS["shown"].key(run, screen)


def control_key(run: str) -> str:
    return KEYS["control"].key(run)


def credit_key(run: str, teacher_id: str) -> str:
    return KEYS["credit"].key(run, teacher_id)


def ingest_key(run: str) -> str:
    return KEYS["ingest"].key(run)


def config_key(run: str) -> str:
    return KEYS["config"].key(run)


@dataclasses.dataclass(frozen=True)
class ParsedKey:
    spec: KeySpec
    run: str
    name: str | None  # teacher_id / service / camera, for keys that have one


def parse_key(key: Any) -> ParsedKey:
    """Concrete key expression -> its row of :data:`KEYS`; ``unknown_key`` if it is not one of ours."""
    if not isinstance(key, str):
        raise ProtocolError("unknown_key", f"key is a {type(key).__name__}")
    return _parse_key(key)


@functools.lru_cache(maxsize=4096)  # a run uses a few dozen keys, each parsed for every message (bounded: hostile keys)
def _parse_key(key: str) -> ParsedKey:
    parts = key.split("/")
    if len(parts) not in (3, 4) or parts[0] != ROOT:
        raise ProtocolError("unknown_key", key[:120])
    spec = KEYS.get(parts[2])
    if spec is None or (len(parts) == 4) != (spec.param is not None):
        raise ProtocolError("unknown_key", key[:120])
    if not _NAME_RE.match(parts[1]) or (len(parts) == 4 and not _NAME_RE.match(parts[3])):
        raise ProtocolError("unknown_key", f"bad name chunk in {key[:120]}")
    return ParsedKey(spec, parts[1], parts[3] if len(parts) == 4 else None)


def kind_of(key: str) -> str:
    """The kind chunk of a key (`step` for `hitl/<run>/step`), or "" if it has none; never raises (for counters
    and filters; `parse_key` validates)."""
    parts = key.split("/", 3) if isinstance(key, str) else []
    return parts[2] if len(parts) >= 3 and parts[0] == ROOT else ""


def message_type(key: str) -> type:
    """The message class carried on a concrete key."""
    return parse_key(key).spec.message


def carried(message: Any) -> list[tuple[str, Any]]:
    """The messages that ride inside another, each with the key it would have had alone: an Ingest's Credits
    (the recorder logs them, and the Foxglove bridge serves them, as if they had come alone)."""
    if isinstance(message, Ingest) and message.credits:
        return [(credit_key(message.run, c.teacher_id), c) for c in message.credits]
    return []


def decode(key: str, data: bytes) -> Any:
    """Decode bytes received on ``key``. Raises only :class:`ProtocolError`.

    A message that names its run (all but the perception types) must name the key's run (``bad_value``),
    and Feedback / ServiceStatus must name the key's teacher / service.
    """
    parsed = parse_key(key)
    msg = parsed.spec.message.decode(data)
    run = getattr(msg, "run", None)
    if run is not None and run != parsed.run:
        raise ProtocolError("bad_value", f"run {run!r} does not match key {key[:120]}")
    if isinstance(msg, (Feedback, ObserverReaction, Credit)) and msg.teacher_id != parsed.name:
        raise ProtocolError("bad_value", f"teacher_id {msg.teacher_id!r} does not match key")
    if isinstance(msg, Shown) and msg.screen != parsed.name:
        raise ProtocolError("bad_value", f"screen {msg.screen!r} does not match key")
    if isinstance(msg, ServiceStatus) and msg.service != parsed.name:
        raise ProtocolError("bad_value", f"service {msg.service!r} does not match key")
    if isinstance(msg, Log) and msg.name != parsed.name:
        raise ProtocolError("bad_value", f"name {msg.name!r} does not match key")
    return msg
