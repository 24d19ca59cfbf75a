"""``python -m services.perception bench``: speed, latency and accuracy of the perception pipeline.

For each frame size (the Pexels clip letterboxed to 320x240 and 640x480, decoded beforehand as a camera
would deliver frames) and for the default pipeline and the naive full-frame Haar detector side by side:

- fps: frames / wall time, and cpu fps: frames / CPU time of the process, on one core (process pinned
  to one CPU, OpenCV and onnxruntime on one thread each);
- capture-to-feedback latency p50 / p99: wall time from handing a frame over to its decision;
- happy-vs-other accuracy on the labelled frames (no face counts as wrong);
- events on the whole clip, and the smoothing lag on a synthetic held smile (30 sad frames, then 60
  smiling frames, at 30 fps): capture time of the +1 minus that of the first smiling frame.

A benchmark, not a test: figures depend on the machine and its load.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import sys
from dataclasses import dataclass
from typing import TextIO

import cv2
import numpy as np

from common.perception import evaluate
from common.perception.models import load_model
from common.perception.pipeline import PerceptionPipeline, PipelineConfig

HELD_SMILE_SAD = range(150, 180)  # 30 frames from the sad segment
HELD_SMILE_HAPPY = range(300, 360)  # 60 frames from the smiling segment = 2 s at 30 fps


@dataclass(frozen=True)
class BenchRow:
    size: str
    detector: str
    fps: float
    cpu_fps: float
    latency_p50_ms: float
    latency_p99_ms: float
    accuracy: float
    no_face: int
    events: str
    smile_events: int
    smile_lag_ms: float | None


def pin_to_one_core() -> str:
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpus[-1]})
        return f"pinned to CPU {cpus[-1]}"
    return "not pinned (no sched_setaffinity)"


def held_smile_clip(frames: list[np.ndarray]) -> list[np.ndarray]:
    return [frames[i] for i in HELD_SMILE_SAD] + [frames[i] for i in HELD_SMILE_HAPPY]


def bench_one(
    pipeline: PerceptionPipeline,
    frames: list[np.ndarray],
    fps: float,
    truth,
    repeats: int,
    size: str,
    name: str,
    frame_step: int = 1,
) -> BenchRow:
    """One row. ``frame_step`` > 1 runs the clip on every n-th frame only (a quick look, not the figure)."""
    main = frames[::frame_step]
    truth = truth[::frame_step]
    runs = [evaluate.run_frames(pipeline, main, fps / frame_step) for _ in range(max(1, repeats))]
    lat = np.concatenate([r.latencies_s for r in runs])
    total = sum(r.total_s for r in runs)
    cpu = sum(r.cpu_s for r in runs)
    acc = evaluate.happy_accuracy(runs[0].predictions, truth)
    events = " ".join(f"{e.value:+d}@{e.frame_index * frame_step}" for e in runs[0].events)
    clip = held_smile_clip(frames)
    smile = evaluate.run_frames(pipeline, clip, 30.0)
    pos = [e for e in smile.events if e.value == 1]
    t_onset = len(HELD_SMILE_SAD) / 30.0
    lag = (pos[0].t_capture - t_onset) * 1000.0 if pos else None
    return BenchRow(
        size,
        name,
        len(lat) / total,
        len(lat) / cpu,
        float(np.percentile(lat, 50) * 1000),
        float(np.percentile(lat, 99) * 1000),
        acc.accuracy,
        acc.no_face,
        events,
        len(pos),
        lag,
    )


def run_bench(
    sizes=((320, 240), (640, 480)),
    repeats: int = 3,
    naive: bool = True,
    one_core: bool = True,
    config: PipelineConfig = PipelineConfig(),
    out: TextIO | None = None,
    as_json: bool = False,
    frame_step: int = 1,
) -> list[BenchRow]:
    out = out or sys.stdout
    pinned = pin_to_one_core() if one_core else "not pinned"
    cv2.setNumThreads(1)
    model = load_model(config.model)  # onnxruntime session on one thread
    rows: list[BenchRow] = []
    variants = [("default", config)]
    if naive:
        variants.append(("haar-full", dataclasses.replace(config, detector="haar-full")))
    for w, h in sizes:
        frames, fps = evaluate.pexels_frames((w, h))
        truth = evaluate.pexels_truth(len(frames))
        for name, cfg in variants:
            pipeline = PerceptionPipeline.from_config(cfg, model=model)
            label = f"{cfg.detector}" if name == "default" else name
            reps = repeats if name == "default" else 1  # the naive rows are slow; one pass shows them
            rows.append(bench_one(pipeline, frames, fps, truth, reps, f"{w}x{h}", label, frame_step))
    if as_json:
        out.write(
            json.dumps(
                {
                    "pinned": pinned,
                    "model": model.name,
                    "config": _describe(config),
                    "rows": [dataclasses.asdict(r) for r in rows],
                },
                indent=2,
            )
            + "\n"
        )
        return rows
    out.write(
        f"perception bench: {platform.processor() or platform.machine()}, {pinned}, "
        f"cv2 {cv2.__version__} threads={cv2.getNumThreads()}, model {model.name} (onnxruntime, 1 thread)\n"
    )
    out.write(f"default pipeline: {_describe(config)}\n")
    step = f", every {frame_step}th frame only" if frame_step > 1 else ""
    out.write(
        f"clip: WolfgangLanger_Pexels.mp4 (472 frames{step}) letterboxed; accuracy on frames 0-223 "
        "(other) + 256-471 (happy); no face counts as wrong\n\n"
    )
    head = (
        f"{'size':8s} {'detector':10s} {'fps':>7s} {'cpu fps':>7s} {'p50 ms':>7s} {'p99 ms':>7s} "
        f"{'happy/other':>11s} {'no face':>7s}  {'held smile: +1s, lag':20s} events on the clip"
    )
    out.write(head + "\n" + "-" * len(head) + "\n")
    for r in rows:
        lag = "-" if r.smile_lag_ms is None else f"{r.smile_lag_ms:.0f} ms"
        out.write(
            f"{r.size:8s} {r.detector:10s} {r.fps:7.1f} {r.cpu_fps:7.1f} {r.latency_p50_ms:7.2f} "
            f"{r.latency_p99_ms:7.2f} {100 * r.accuracy:10.1f}% {r.no_face:7d}  "
            f"{r.smile_events:d} x +1, {lag:11s}       {r.events}\n"
        )
    out.write(
        "\nfps: frames / wall time; cpu fps: frames / CPU time of this process (what one free core "
        "sustains);\nlatency: wall time from handing a frame over to its decision; held smile: 30 sad "
        "then 60 smiling frames at 30 fps,\nlag = capture time of the +1 minus that of the first "
        "smiling frame (the smoothing's delay).\n"
    )
    out.flush()
    return rows


def _describe(c: PipelineConfig) -> str:
    r = c.reaction
    return (
        f"detector={c.detector} (full Haar search on a {c.detect_width}-px-wide copy"
        f"{', local search in between' if c.detector == 'tracking' else ''}), model={c.model}, "
        f"EMA tau={r.tau_s}s, on>={r.on_threshold}, re-arm<{r.off_threshold}"
    )
