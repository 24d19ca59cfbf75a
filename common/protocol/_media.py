"""Messages of the camera and perception path and of the services' logs, in Foxglove's JSON schemas (its `Log`,
`CompressedImage`) and ours (`ExpressionPrediction`, and the video observer's `ObserverReaction`)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar
from ._base import Map, Message, Nullable, Obj, fld
from ._fields import RUN, Count, Name, Seconds
from ._spec import Bytes64, Float, Int, ProtocolError, Str


LOG_LEVELS = {0: "UNKNOWN", 1: "DEBUG", 2: "INFO", 3: "WARNING", 4: "ERROR", 5: "FATAL"}


@dataclasses.dataclass(frozen=True)
class Time:
    """foxglove.Time: seconds and nanoseconds since the Unix epoch."""

    sec: int
    nsec: int

    @classmethod
    def from_seconds(cls, t: float) -> Time:
        ns = int(round(t * 1e9))
        return cls(ns // 1_000_000_000, ns % 1_000_000_000)

    def to_seconds(self) -> float:
        return self.sec + self.nsec * 1e-9


TIME_SPEC = Obj(
    {"sec": Int(0, 2**32 - 1), "nsec": Int(0, 999_999_999)}, cls=Time, description="Capture time (foxglove.Time)."
)


@dataclasses.dataclass(frozen=True)
class Log(Message):
    """A human-readable event, exactly Foxglove's `foxglove.Log` in its JSON form (published on
    `hitl/<run>/log/<name>`): the launcher's supervision (a service died, was restarted, gave up), a learner's
    restore and catch-up, the first rejected input of each reason. Foxglove lists them in its Log panel."""

    TYPE_NAME: ClassVar[str] = "foxglove.Log"
    MAX_BYTES: ClassVar[int] = 16 * 1024

    timestamp: Time = fld(
        Obj(
            {"sec": Int(0, 2**32 - 1), "nsec": Int(0, 999_999_999)},
            cls=Time,
            description="Time of the event (foxglove.Time).",
        )
    )
    level: int = fld(
        Int(
            enum=tuple(LOG_LEVELS),
            description=("0 unknown, 1 debug, 2 info, 3 warning, 4 error, 5 fatal (foxglove.LogLevel)."),
        )
    )
    message: str = fld(Str(8192, description="What happened."))
    name: str = fld(Str(64, description="Who says it: the service name (the key's last chunk)."))
    file: str = fld(Str(256, description="Source file (may be empty)."))
    line: int = fld(Int(0, 2**32 - 1, description="Source line (0 if unknown)."))


@dataclasses.dataclass(frozen=True)
class CompressedImage(Message):
    """A camera frame, exactly Foxglove's `foxglove.CompressedImage` in its JSON form (published on
    `hitl/<run>/camera/<id>`), so Foxglove shows the recorded stream as an image."""

    TYPE_NAME: ClassVar[str] = "foxglove.CompressedImage"
    MAX_BYTES: ClassVar[int] = 8 * 1024 * 1024

    timestamp: Time = fld(TIME_SPEC)
    frame_id: str = fld(Str(256, description="Frame of reference (the camera id)."))
    data: bytes = fld(Bytes64(6 * 1024 * 1024, description="Compressed image bytes (base64 in JSON)."))
    format: str = fld(Str(enum=("jpeg", "png", "webp"), description="Image format."))


@dataclasses.dataclass(frozen=True)
class Box:
    """A face box in pixels."""

    x: int
    y: int
    w: int
    h: int


BOX_SPEC = Obj(
    {"x": Int(0, 65535), "y": Int(0, 65535), "w": Int(0, 65535), "h": Int(0, 65535)},
    cls=Box,
    description="Face box in pixels (x, y of the top-left corner, width, height).",
)


@dataclasses.dataclass(frozen=True)
class ExpressionPrediction(Message):
    """What the perception service read from one camera frame (published on `hitl/<run>/perception/<id>`)."""

    TYPE_NAME: ClassVar[str] = "hitl.ExpressionPrediction"
    MAX_BYTES: ClassVar[int] = 8192

    t_capture: float = fld(Seconds("Wall-clock time (s) when the frame was captured."))
    frame: int = fld(Count("Frame index in the camera stream."))
    box: Box | None = fld(Nullable(BOX_SPEC, description="Face box, or null when no face was found."))
    label: str = fld(Str(32, description="Most probable expression label (empty when no face)."))
    confidence: float = fld(Float(0.0, 1.0, description="Probability of `label`."))
    probabilities: dict = fld(
        Map(Float(0.0, 1.0), max_items=16, key_max_len=32, description="Probability of each label.")
    )


@dataclasses.dataclass(frozen=True)
class ObserverReaction(Message):
    """Diagnostics of a video-backed observer (the `face-video` teacher): one reaction it showed to the camera.

    Published on `hitl/<run>/reaction/<teacher_id>` when the clip starts. The perception service turns the
    frames into Feedback on `hitl/<run>/feedback/<teacher_id>`; comparing the two measures the perception
    path (polarity errors, missed and extra reactions, lag). Never learned from.
    """

    TYPE_NAME: ClassVar[str] = "hitl.ObserverReaction"
    MAX_BYTES: ClassVar[int] = 4096
    CROSS_RULES: ClassVar[tuple[str, ...]] = ("`t_end >= t_start`, else `bad_value`",)

    run: str = fld(Name(RUN))
    teacher_id: str = fld(
        Name("The teacher whose Feedback these frames should become; also the last chunk of the key.")
    )
    seq: int = fld(Count("Reaction counter per teacher, without gaps."))
    ref_seq: int = fld(Count("The Step.seq the observer reacted to."))
    lag_steps: int = fld(Count("The observer's true lag in steps (drawn from its delay distribution)."))
    value: int = fld(Int(enum=(-1, 1), description="The polarity shown (after a simulated misread, if any)."))
    intended: int = fld(Int(enum=(-1, 1), description="The observer's judgement before a simulated misread."))
    t_start: float = fld(Seconds("Capture time (s) of the first frame showing the expression."))
    t_end: float = fld(Seconds("Capture time (s) of the last frame showing it."))
    camera: str = fld(Name("Camera id (key chunk) the frames were published on."))
    clip: str = fld(Str(64, description="The frames shown, e.g. `pexels:256-273`."))

    def _cross_check(self) -> None:
        if self.t_end < self.t_start:
            raise ProtocolError("bad_value", f"t_end {self.t_end} is before t_start {self.t_start}")
