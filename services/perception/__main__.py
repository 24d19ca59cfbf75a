"""Perception: a face on video -> binary feedback (+1 smile, -1 frown/sad/angry/...).

The live service (frames in, ExpressionPrediction and Feedback out over Zenoh; see ``live.py``)::

    python -m services.perception --source SOURCE [--connect tcp/127.0.0.1:7447] [--run RUN] [--teacher-id face]

SOURCE: a video file, an image or a folder, ``camera:N``, ``mcap:LOG.mcap`` (re-run perception on a recorded
session's camera frames) or ``zenoh:CAMERA`` (frames published on hitl/<run>/camera/CAMERA).

Offline subcommands (no network):

    python -m services.perception classify PATH [--json] [--every N] [--model M] [--detector D]
    python -m services.perception bench [--sizes 320x240,640x480] [--repeats 3] [--no-naive] [--json]

``run_pipeline(config, sink)`` runs the pure pipeline over a ``PerceptionServiceConfig`` source and hands
each decision to a ``sink`` (what tests and other programs embed; no Zenoh).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

from common.config import Command, option, run_commands
from common.perception.assets import AssetsMissingError
from common.perception.media import MediaError
from common.perception.pipeline import PerceptionPipeline, PipelineConfig
from common.perception.reaction import FeedbackEvent, FramePrediction

from .config import PerceptionServiceConfig

Sink = Callable[[FramePrediction, FeedbackEvent | None], None]


def run_pipeline(config: PerceptionServiceConfig, sink: Sink | None = None) -> int:
    """Run the pipeline over ``config.source`` and pass every (prediction, event) to ``sink``.

    Returns the number of feedback events. Transport (Zenoh publishing, recording) belongs in the sink
    the caller passes; this function never imports zenoh.
    """
    from .classify import format_line
    from .sources import open_source

    pipeline = PerceptionPipeline.from_config(config.pipeline)
    emit = sink or (lambda pred, event: print(format_line(pred, event), flush=True))
    events = processed = 0
    for frame in open_source(config.source_spec, config.every, config.realtime):
        pred, event = pipeline.process(frame.image, frame.index, frame.t_capture)
        emit(pred, event)
        events += event is not None
        processed += 1
        if config.max_frames is not None and processed >= config.max_frames:
            break
    return events


@dataclass(frozen=True)
class _PipelineOptions:
    model: str = option(
        PipelineConfig.model, "mini-xception, haar-smile, or a model config .json/.toml (see docs/perception.md)"
    )
    detector: str = option(PipelineConfig.detector, "face detector", choices=("tracking", "haar", "haar-full"))
    detect_width: int = option(PipelineConfig.detect_width, "width of the copy the full face search runs on")

    def pipeline(self) -> PipelineConfig:
        return PipelineConfig(detector=self.detector, detect_width=self.detect_width, model=self.model)


@dataclass(frozen=True)
class ClassifyConfig(_PipelineOptions):
    """Print expression and feedback per frame of a video or per image (offline, no network)."""

    path: str = option(
        "", "a video file, an image, a folder of images, or mcap:LOG.mcap (a session's frames)", positional=True
    )
    json: bool = option(False, "one JSON object per line")
    every: int = option(1, "process every N-th frame only")

    def __post_init__(self):
        if self.every < 1:
            raise ValueError("--every must be >= 1")


def _parse_sizes(text: str) -> tuple[tuple[int, int], ...]:
    sizes = []
    for part in text.split(","):
        try:
            w, h = part.lower().split("x")
            sizes.append((int(w), int(h)))
        except ValueError:
            raise ValueError(f"--sizes: {part!r} is not WIDTHxHEIGHT") from None
    return tuple(sizes)


@dataclass(frozen=True)
class PerceptionBenchConfig(_PipelineOptions):
    """Fps, capture-to-feedback latency and accuracy on the labelled clip (offline, no network)."""

    sizes: str = option("320x240,640x480", "frame sizes, WIDTHxHEIGHT, comma-separated")
    repeats: int = option(3, "passes over the clip per row")
    no_naive: bool = option(False, "skip the naive full-frame Haar rows")
    all_cores: bool = option(False, "do not pin the process to one CPU")
    frame_step: int = option(1, "quick look: run the clip on every N-th frame only")
    json: bool = option(False, "print the rows as JSON")

    def __post_init__(self):
        _parse_sizes(self.sizes)


def _offline(run):
    def guarded(args) -> int:
        try:
            return run(args)
        except (MediaError, AssetsMissingError, FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # e.g. piped into head
            return 0

    return guarded


def _classify(args: ClassifyConfig) -> int:
    from .classify import classify

    classify(args.path, args.pipeline(), as_json=args.json, every=args.every)
    return 0


def _bench(args: PerceptionBenchConfig) -> int:
    from .bench import run_bench

    run_bench(
        sizes=_parse_sizes(args.sizes),
        repeats=args.repeats,
        naive=not args.no_naive,
        one_core=not args.all_cores,
        config=args.pipeline(),
        as_json=args.json,
        frame_step=max(1, args.frame_step),
    )
    return 0


SUBCOMMANDS = {
    "classify": Command(ClassifyConfig, _offline(_classify)),
    "bench": Command(PerceptionBenchConfig, _offline(_bench)),
}


def main(config):
    """The live service (``live.main``): ``main(PerceptionLiveConfig(...))``."""
    from .live import main as live_main

    return live_main(config)


def cli(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in SUBCOMMANDS:
        from .live import cli as live_cli

        return live_cli(argv)
    return run_commands("python -m services.perception", __doc__.split("\n\n")[0], SUBCOMMANDS, argv)


if __name__ == "__main__":
    sys.exit(cli())
