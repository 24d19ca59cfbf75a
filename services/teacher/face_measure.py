"""`python -m services.teacher face-video measure`: what the perception path does to the face-video observer's
reactions, offline (no Zenoh, no timing noise).

Every possible clip start in the smiling (+1) and sad (-1) parts of the labelled clip (or a sample of them) is
played as the observer plays it: frames scaled to `--width`, JPEG-encoded and decoded, stamped at the clip's
frame rate, after an empty gap longer than the reaction detector's `lost_after_s` (so each reaction starts
fresh), through the default pipeline. For each clip length it reports how many reactions fired, with the
wrong polarity, more than once, and the lag from the clip's first frame to the frame that fired. The pipeline
is causal, so a clip of N frames fires exactly as the first N frames of a longer one: each start is run once.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

import numpy as np

from common.config import option, parse_config


def _decoded(decode_image, data: bytes) -> np.ndarray:
    """A clip frame as an image; the library's own frames always decode (else it is damaged: say so)."""
    image = decode_image(data)
    if image is None:
        raise ValueError("face clip library: a frame does not decode (rebuild it: `make setup`)")
    return image


def measure(
    clip_lengths_s: list[float], width: int = 320, quality: int = 80, step: int = 1, gap_s: float = 0.6
) -> dict:
    import cv2

    from common.perception.pipeline import PerceptionPipeline, PipelineConfig
    from services.perception.sources import decode_image
    from services.teacher.face_video import ClipLibrary

    lib = ClipLibrary.load(width, quality)
    fps = lib.fps
    lengths = sorted({max(1, int(round(s * fps))) for s in clip_lengths_s})
    n_max = lengths[-1]
    blank = _decoded(decode_image, lib.blank)
    pipe = PerceptionPipeline.from_config(PipelineConfig())
    cv2.setNumThreads(1)
    decoded: dict[int, np.ndarray] = {}
    t, index = 0.0, 0
    runs: dict[int, list[list[tuple[int, int]]]] = {1: [], -1: []}
    gap_frames = max(1, int(round(gap_s * fps)))
    for value, seg in lib.segments.items():
        for start in range(seg.start, seg.stop - n_max + 1, step):
            for _ in range(gap_frames):
                pipe.process(blank, index, t)
                index += 1
                t += 1.0 / fps
            events = []
            for k in range(n_max):
                i = start + k
                if i not in decoded:
                    decoded[i] = _decoded(decode_image, lib.frames[i])
                _, ev = pipe.process(decoded[i], index, t)
                if ev is not None:
                    events.append((int(ev.value), k))
                index += 1
                t += 1.0 / fps
            runs[value].append(events)
    rows = []
    for n in lengths:
        for value in (1, -1):
            clips = [[e for e in evs if e[1] < n] for evs in runs[value]]
            fired = [c for c in clips if c]
            lags = np.array([c[0][1] / fps for c in fired]) if fired else np.array([])
            rows.append(
                {
                    "clip_s": round(n / fps, 3),
                    "clip_frames": n,
                    "value": value,
                    "clips": len(clips),
                    "fired": len(fired),
                    "missed": len(clips) - len(fired),
                    "wrong_polarity": sum(c[0][0] != value for c in fired),
                    "extra": sum(len(c) - 1 for c in fired),
                    "lag_s": None
                    if not fired
                    else {
                        q: round(float(np.percentile(lags, p)), 3)
                        for q, p in (("p10", 10), ("p50", 50), ("p90", 90), ("max", 100))
                    },
                }
            )
    return {"width": width, "size": list(lib.size), "fps": round(fps, 3), "gap_s": gap_s, "rows": rows}


def format_rows(result: dict) -> str:
    lines = [
        f"frames {result['size'][0]}x{result['size'][1]} at {result['fps']} fps, gap {result['gap_s']} s",
        "clip_s  value  clips  fired  missed  wrong  extra   lag p10   p50   p90   max",
    ]
    for r in result["rows"]:
        lag = r["lag_s"] or {}
        lines.append(
            f"{r['clip_s']:6.3f}  {r['value']:+d}    {r['clips']:5d}  {r['fired']:5d}  {r['missed']:6d}  "
            f"{r['wrong_polarity']:5d}  {r['extra']:5d}   "
            + "  ".join(f"{lag.get(q, float('nan')):5.3f}" for q in ("p10", "p50", "p90", "max"))
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class FaceMeasureConfig:
    """What the perception path does to the face-video observer's reactions, offline: per clip length, reactions
    fired, missed, with the wrong polarity, more than once, and their lag."""

    clip_s: tuple[float, ...] = option((0.5, 0.75, 1.0), "clip lengths to report (s, comma-separated)")
    width: int = option(320, "frame width the clips are scaled to")
    jpeg_quality: int = option(80, "JPEG quality of the frames")
    step: int = option(1, "every N-th clip start only (quick look)")
    json: bool = option(False, "print the result as JSON")


def cli(argv: list[str] | None = None) -> int:
    args = parse_config(FaceMeasureConfig, argv, prog="python -m services.teacher face-video measure")
    from common.perception.assets import AssetsMissingError

    try:
        result = measure(list(args.clip_s), args.width, args.jpeg_quality, max(1, args.step))
    except AssetsMissingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result) if args.json else format_rows(result))
    return 0
