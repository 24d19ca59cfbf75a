"""The face-video observer's config (`python -m services.teacher.face_video --help`): the simulated observer whose
reactions are shown to a camera as clips of a real face."""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.config import option
from common.core.delay import parse_probs
from common.protocol import observer_service_name
from services.common.config import TaskConfig, _check_name
from services.teacher.face_launch import DEFAULT_RATE


@dataclass(frozen=True)
class FaceVideoConfig(TaskConfig):
    """The face-video observer: the simulated observer's reactions shown to a camera as clips of a real face."""

    teacher_id: str = option(
        "face",
        "the teacher these reactions are for (the perception service's teacher id); "
        "this service is observer.<teacher_id>",
    )
    camera: str = option("face", "camera id: frames go to hitl/<run>/camera/<camera>")
    p_feedback: float = option(0.5, "probability that the observer reacts to a step")
    delay_probs: tuple[float, ...] = option((0.3, 0.6, 0.1), "true lag distribution over 0,1,2.. steps")
    flip: float = option(
        0.0,
        "probability that the observer shows the opposite expression (a simulated misread, "
        "on top of the perception's own errors)",
    )
    stop_episode: int | None = option(None, "silent from this episode on (0-based); none = never")
    stop_step: int | None = option(None, "silent from this global step on; none = never")
    step_unit: float = option(1.0 / DEFAULT_RATE, "seconds per step (1 / the actor's rate): the unit of the lags")
    clip_s: float = option(0.75, "seconds of expression per reaction")
    gap_s: float = option(0.6, "seconds without a face after each clip (> the reaction detector's lost_after_s)")
    width: int = option(320, "frame width in pixels (the 640x360 clip is scaled, aspect kept)")
    jpeg_quality: int = option(80, "JPEG quality")
    state_file: str | None = option(
        None, "progress file (the next ObserverReaction seq), so a restarted observer continues the seq"
    )

    def __post_init__(self):
        super().__post_init__()
        _check_name(self.teacher_id, "teacher-id")
        _check_name(self.camera, "camera")
        for name in ("p_feedback", "flip"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise ValueError(f"{name.replace('_', '-')} must be in [0, 1], got {v}")
        object.__setattr__(self, "delay_probs", parse_probs(self.delay_probs, "delay-probs"))
        for name in ("step_unit", "clip_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name.replace('_', '-')} must be positive, got {v}")
        if not (math.isfinite(self.gap_s) and self.gap_s >= 0):
            raise ValueError(f"gap-s must be >= 0, got {self.gap_s}")
        if not 32 <= self.width <= 1920:
            raise ValueError(f"width must be in 32..1920, got {self.width}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg-quality must be in 1..100, got {self.jpeg_quality}")

    @property
    def service_name(self) -> str:
        return observer_service_name(self.teacher_id)
