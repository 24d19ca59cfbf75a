"""Frame in, (prediction, feedback event or None) out: face detector + expression model + reaction detector.

Pure with respect to transport: a live service feeds frames from a camera or a Zenoh subscription and
publishes the events; tests and the CLI feed frames from files.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .faces import FaceDetector, make_detector
from .models import ExpressionModel, load_model
from .reaction import FeedbackEvent, FramePrediction, ReactionConfig, ReactionDetector


@dataclass(frozen=True)
class PipelineConfig:
    """The default pipeline: Haar face detection on a 160-px-wide copy with tracking between full
    searches every 15 frames, fer's mini-Xception on onnxruntime (one thread), time-based EMA smoothing
    with hysteresis."""

    detector: str = "tracking"  # tracking | haar | haar-full
    detect_width: int = 160  # width of the copy the full-frame face search runs on
    model: str = "mini-xception"  # mini-xception | haar-smile | path to a model config
    reaction: ReactionConfig = field(default_factory=ReactionConfig)
    opencv_threads: int = 1


class PerceptionPipeline:
    def __init__(
        self, detector: FaceDetector, model: ExpressionModel, reaction: ReactionDetector | None = None
    ) -> None:
        self.detector = detector
        self.model = model
        self.reaction = reaction or ReactionDetector()
        self.labels = tuple(model.labels)

    @classmethod
    def from_config(
        cls, config: PipelineConfig = PipelineConfig(), model: ExpressionModel | None = None
    ) -> PerceptionPipeline:
        if config.opencv_threads:
            cv2.setNumThreads(config.opencv_threads)
        return cls(
            make_detector(config.detector, config.detect_width),
            model if model is not None else load_model(config.model),
            ReactionDetector(config.reaction),
        )

    def reset(self) -> None:
        """Forget tracking and smoothing state (start of a new clip, or between unrelated images)."""
        self.detector.reset()
        self.reaction.reset()

    def predict(self, image: np.ndarray, index: int = 0, t_capture: float = 0.0) -> FramePrediction:
        if image.ndim == 2:
            gray, bgr = image, None
        elif image.shape[2] == 1:
            gray, bgr = image[:, :, 0], None
        else:
            bgr = image if image.shape[2] == 3 else cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
            gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        box = self.detector.detect(gray)
        if box is None:
            return FramePrediction(index, t_capture, None, self.labels, None)
        probs = self.model.predict(gray, box, bgr)
        return FramePrediction(index, t_capture, box, self.labels, tuple(float(p) for p in probs))

    def process(
        self, image: np.ndarray, index: int = 0, t_capture: float = 0.0
    ) -> tuple[FramePrediction, FeedbackEvent | None]:
        pred = self.predict(image, index, t_capture)
        return pred, self.reaction.update(pred)
