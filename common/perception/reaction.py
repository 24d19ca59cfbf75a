"""Per-frame expression predictions in, debounced binary feedback events out. Pure and deterministic.

``ReactionDetector.update(prediction)`` takes one ``FramePrediction`` (face box or none, probabilities
over the model's labels, capture time) and returns a ``FeedbackEvent`` or None:

1. The label probabilities are summed into three polarities (positive, negative, none) with
   ``models.label_feedback`` (happy +1; anger, contempt, disgust, fear, sadness -1; the rest none).
2. Smoothing: an exponential moving average over *time* (time constant ``tau_s``), so the behaviour is
   the same at 24 or 30 fps: ``s += (1 - exp(-dt / tau_s)) * (p - s)``. A new face starts from
   (0, 0, 1), "no reaction"; with the defaults a clear expression fires after about 0.3 s (9-10 frames
   at 30 fps), and ``tau_s = 0`` turns smoothing off (each frame judged alone, as for still images).
   Why 0.25 s and 0.7: in the sad part of the labelled clip a crying grimace reads as "happy" for about
   half a second; with tau 0.15 s and 0.6 it fired a false +1, with these its smoothed probability
   peaks at 0.55-0.60, below the threshold (see docs/perception.md).
3. Hysteresis per polarity: an armed polarity fires once when its smoothed probability reaches
   ``on_threshold``; it re-arms only after it has fallen below ``off_threshold``. A held smile
   therefore gives exactly one +1; a new +1 needs the smile to go away first.
4. No face: a frame without a face never fires and does not move the average. Short detector dropouts
   (up to ``lost_after_s``) keep the state; a longer absence resets it (average cleared, all re-armed),
   so a face that comes back starts fresh.

Each event carries the capture time and index of the frame whose prediction made it fire.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from collections.abc import Iterable, Sequence

import numpy as np

from .faces import FaceBox
from .models import polarity_weights


@dataclass(frozen=True)
class FramePrediction:
    """What the classifier said about one frame. ``probs`` is None when no face was found."""

    index: int
    t_capture: float  # seconds, on the clock of the frame source (camera time, or index / fps for files)
    box: FaceBox | None
    labels: tuple[str, ...]
    probs: tuple[float, ...] | None

    @property
    def label(self) -> str | None:
        if self.probs is None:
            return None
        return self.labels[int(np.argmax(self.probs))]

    @property
    def confidence(self) -> float:
        return float(max(self.probs)) if self.probs is not None else 0.0


@dataclass(frozen=True)
class FeedbackEvent:
    """A binary feedback decision: +1 or -1, stamped with the capture time of the triggering frame."""

    value: int
    t_capture: float
    frame_index: int
    confidence: float  # smoothed probability of this polarity when it fired
    label: str | None  # the frame's top label (for logs)


@dataclass(frozen=True)
class ReactionConfig:
    tau_s: float = 0.25  # EMA time constant
    on_threshold: float = 0.7  # smoothed polarity probability that fires an event
    off_threshold: float = 0.35  # ... and below which that polarity re-arms
    lost_after_s: float = 0.5  # a face missing longer than this resets the detector
    max_dt_s: float = 1.0  # a larger gap between frames is treated as this (robust to stalls)
    first_dt_s: float = 1.0 / 30.0  # the first face frame moves the average from "none" by this much time
    enable_negative: bool = True  # emit -1 events (else only +1)

    def __post_init__(self) -> None:
        if not 0.0 <= self.off_threshold < self.on_threshold <= 1.0 or self.on_threshold <= 0.5:
            # above one half, at most one polarity can be over the threshold at a time
            raise ValueError("need 0 <= off_threshold < on_threshold <= 1 and on_threshold > 0.5")
        if self.tau_s < 0:
            raise ValueError("tau_s must be >= 0")


@dataclass
class _State:
    smoothed: np.ndarray | None = None  # (positive, negative, none)
    armed: list[bool] = field(default_factory=lambda: [True, True])
    t_last: float | None = None  # capture time of the last frame with a face


class ReactionDetector:
    """Debounced feedback from a stream of ``FramePrediction``; see the module docstring."""

    def __init__(self, config: ReactionConfig = ReactionConfig()) -> None:
        self.config = config
        self._weights_cache: dict[tuple[str, ...], np.ndarray] = {}
        self.reset()

    def reset(self) -> None:
        self.state = _State()

    @property
    def smoothed(self) -> tuple[float, float, float] | None:
        s = self.state.smoothed
        return None if s is None else (float(s[0]), float(s[1]), float(s[2]))

    def _weights(self, labels: tuple[str, ...]) -> np.ndarray:
        w = self._weights_cache.get(labels)
        if w is None:
            w = self._weights_cache[labels] = polarity_weights(labels).astype(np.float64)
        return w

    def update(self, pred: FramePrediction) -> FeedbackEvent | None:
        c, st = self.config, self.state
        if pred.probs is None or pred.box is None:
            if st.t_last is not None and pred.t_capture - st.t_last > c.lost_after_s:
                self.reset()
            return None
        p = self._weights(tuple(pred.labels)) @ np.asarray(pred.probs, dtype=np.float64)
        total = p.sum()
        p = p / total if total > 0 else np.array([0.0, 0.0, 1.0])
        if st.smoothed is None or st.t_last is None:
            # A new face starts from "no reaction", so one odd first frame cannot fire on its own.
            st.smoothed = np.array([0.0, 0.0, 1.0])
            dt = c.first_dt_s
        else:
            dt = min(max(pred.t_capture - st.t_last, 0.0), c.max_dt_s)
        alpha = 1.0 if c.tau_s == 0 else 1.0 - math.exp(-dt / c.tau_s)
        st.smoothed = st.smoothed + alpha * (p - st.smoothed)
        st.t_last = pred.t_capture
        event = None
        for k, value in ((0, 1), (1, -1)):
            s = float(st.smoothed[k])
            if st.armed[k]:
                if s >= c.on_threshold and (value == 1 or c.enable_negative):
                    st.armed[k] = False
                    event = FeedbackEvent(value, pred.t_capture, pred.index, s, pred.label)
            elif s < c.off_threshold:
                st.armed[k] = True
        return event

    def run(self, preds: Iterable[FramePrediction]) -> list[FeedbackEvent]:
        """Feed a whole sequence (from the current state) and return the events it produced."""
        return [e for e in (self.update(p) for p in preds) if e is not None]


def synthetic_predictions(
    sequence: Sequence[str | None],
    fps: float = 30.0,
    labels: tuple[str, ...] = ("happy", "sad", "neutral"),
    confidence: float = 1.0,
    t0: float = 0.0,
) -> list[FramePrediction]:
    """Predictions for a label per frame (None = no face), for tests and examples."""
    out = []
    box = FaceBox(0, 0, 10, 10)
    for i, lab in enumerate(sequence):
        if lab is None:
            out.append(FramePrediction(i, t0 + i / fps, None, labels, None))
            continue
        rest = (1.0 - confidence) / max(1, len(labels) - 1)
        probs = tuple(confidence if label == lab else rest for label in labels)
        out.append(FramePrediction(i, t0 + i / fps, box, labels, probs))
    return out
