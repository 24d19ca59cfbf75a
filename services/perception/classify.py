"""``python -m services.perception classify PATH``: one line per frame (video) or per image.

Each line: frame index, capture time, face box or none, top label, its confidence, and the debounced
feedback event if one fires on that frame. For images each one is judged alone (no smoothing): the
feedback column then says what that expression would give if held.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from typing import TextIO

from common.perception.pipeline import PerceptionPipeline, PipelineConfig
from common.perception.reaction import FeedbackEvent, FramePrediction

from .config import SourceSpec
from .sources import open_source


def format_line(pred: FramePrediction, event: FeedbackEvent | None, source: str | None = None) -> str:
    box = "none" if pred.box is None else "[" + ",".join(str(v) for v in pred.box.as_list()) + "]"
    label = pred.label or "-"
    fb = "" if event is None else f"{event.value:+d}"
    src = f"  {source}" if source else ""
    return (
        f"frame {pred.index:5d}  t={pred.t_capture:8.3f}s  box={box:20s}  {label:8s} "
        f"{pred.confidence:.2f}  feedback={fb}{src}"
    ).rstrip()


def format_json(pred: FramePrediction, event: FeedbackEvent | None, source: str | None = None) -> str:
    rec = {
        "frame": pred.index,
        "t_capture": round(pred.t_capture, 6),
        "box": None if pred.box is None else pred.box.as_list(),
        "label": pred.label,
        "confidence": round(pred.confidence, 4),
        "probs": None if pred.probs is None else {label: round(p, 4) for label, p in zip(pred.labels, pred.probs)},
        "feedback": None if event is None else event.value,
    }
    if source:
        rec["source"] = source
    return json.dumps(rec)


def classify(
    path: str,
    config: PipelineConfig = PipelineConfig(),
    as_json: bool = False,
    every: int = 1,
    out: TextIO | None = None,
) -> int:
    """Classify every ``every``-th frame of ``path`` (a video, an image or a folder of images).

    Returns the number of feedback events. Raises ``MediaError`` / ``AssetsMissingError`` /
    ``FileNotFoundError`` with a readable message for bad paths or a missing model.
    """
    out = out or sys.stdout
    spec = SourceSpec.parse(path)
    if spec.kind not in ("video", "image", "mcap"):
        raise ValueError(
            f"classify reads files and logs; {path!r} is a live source "
            f"(python -m services.perception --source {path} reads it)"
        )
    stills = spec.kind == "image"
    if stills:  # each image alone: no smoothing across unrelated pictures
        config = dataclasses.replace(config, reaction=dataclasses.replace(config.reaction, tau_s=0.0))
    pipeline = PerceptionPipeline.from_config(config)
    fmt = format_json if as_json else format_line
    events = 0
    for frame in open_source(spec, every):
        if stills:
            pipeline.reset()
        pred, event = pipeline.process(frame.image, frame.index, frame.t_capture)
        events += event is not None
        out.write(fmt(pred, event, frame.source if stills else None) + "\n")
    out.flush()
    return events
