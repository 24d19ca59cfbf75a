"""Accuracy on the labelled Pexels clip and speed/latency measurement of a pipeline.

Happy-vs-other accuracy: on frames 0-223 (sad, truth "other") and 256-471 (smiling, truth "happy"),
the transition in between skipped, a frame counts as correct when the top label's polarity matches
(happy vs anything else). A frame where no face is found counts as **wrong** (the pipeline gave no
answer), so detection misses lower the figure.

Speed: frames are decoded and resized beforehand (as a camera would deliver them); each frame's
capture-to-feedback latency is the wall time from handing the frame to ``PerceptionPipeline.process``
until its decision (event or none) is out. fps = frames / total processing time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from collections.abc import Callable, Sequence

import numpy as np

from . import assets
from .media import letterbox, load_video
from .models import label_feedback
from .pipeline import PerceptionPipeline
from .reaction import FeedbackEvent, FramePrediction


def pexels_frames(size: tuple[int, int] | None = None) -> tuple[list[np.ndarray], float]:
    """The Pexels clip's frames, letterboxed to ``size`` (width, height) if given, and its fps."""
    frames, fps = load_video(assets.media_path("pexels"))
    if size is not None:
        frames = [letterbox(f, size[0], size[1]) for f in frames]
    return frames, fps


def pexels_truth(n: int) -> list[bool | None]:
    labels = assets.PexelsLabels()
    return [labels.label(i) for i in range(n)]


@dataclass(frozen=True)
class AccuracyReport:
    accuracy: float  # correct / labelled frames (no face = wrong)
    labelled: int
    correct: int
    no_face: int
    happy_recall: float
    other_recall: float

    def line(self) -> str:
        return (
            f"happy-vs-other {100 * self.accuracy:.1f}% ({self.correct}/{self.labelled}; "
            f"no face {self.no_face}; happy recall {100 * self.happy_recall:.1f}%, "
            f"other recall {100 * self.other_recall:.1f}%)"
        )


def is_happy(pred: FramePrediction) -> bool | None:
    return None if pred.label is None else label_feedback(pred.label) == 1


def happy_accuracy(preds: Sequence[FramePrediction], truth: Sequence[bool | None]) -> AccuracyReport:
    correct = labelled = no_face = 0
    hits = {True: 0, False: 0}
    counts = {True: 0, False: 0}
    for pred, t in zip(preds, truth):
        if t is None:
            continue
        labelled += 1
        counts[t] += 1
        h = is_happy(pred)
        if h is None:
            no_face += 1
        elif h == t:
            correct += 1
            hits[t] += 1
    return AccuracyReport(
        correct / max(1, labelled),
        labelled,
        correct,
        no_face,
        hits[True] / max(1, counts[True]),
        hits[False] / max(1, counts[False]),
    )


@dataclass(frozen=True)
class RunResult:
    predictions: list[FramePrediction]
    events: list[FeedbackEvent]
    latencies_s: np.ndarray  # per frame, capture -> decision (wall clock)
    total_s: float  # wall time of the whole run
    cpu_s: float = float("nan")  # CPU time of this process during the run (all threads)

    @property
    def fps(self) -> float:
        return len(self.latencies_s) / self.total_s if self.total_s > 0 else float("inf")

    @property
    def cpu_fps(self) -> float:
        """Frames per CPU-second: what one free core would sustain, less sensitive to other load."""
        return len(self.latencies_s) / self.cpu_s if self.cpu_s > 0 else float("inf")

    def latency_ms(self, q: float) -> float:
        return float(np.percentile(self.latencies_s, q) * 1000.0)


def run_frames(
    pipeline: PerceptionPipeline,
    frames: Sequence[np.ndarray],
    fps: float,
    clock: Callable[[], float] = time.perf_counter,
) -> RunResult:
    """Feed frames in order (stamped index / fps for the detector) and time each decision."""
    pipeline.reset()
    preds, events, lat = [], [], np.empty(len(frames))
    cpu0 = time.process_time()
    start = clock()
    for i, img in enumerate(frames):
        t0 = clock()
        pred, ev = pipeline.process(img, i, i / fps)
        lat[i] = clock() - t0
        preds.append(pred)
        if ev is not None:
            events.append(ev)
    total = clock() - start
    return RunResult(preds, events, lat, total, time.process_time() - cpu0)
