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

import argparse
import sys
from collections.abc import Callable

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


def _add_pipeline_args(p: argparse.ArgumentParser) -> None:
    d = PipelineConfig()
    p.add_argument("--model", default=d.model,
                   help="mini-xception (default), haar-smile, or a model config .json/.toml (see docs/perception.md)")
    p.add_argument("--detector", default=d.detector, choices=["tracking", "haar", "haar-full"],
                   help="face detector (default: %(default)s)")
    p.add_argument("--detect-width", type=int, default=d.detect_width,
                   help="width of the copy the full face search runs on (default: %(default)s)")


def _pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    return PipelineConfig(detector=args.detector, detect_width=args.detect_width, model=args.model)


def _parse_sizes(text: str) -> list[tuple[int, int]]:
    sizes = []
    for part in text.split(","):
        try:
            w, h = part.lower().split("x")
            sizes.append((int(w), int(h)))
        except ValueError:
            raise argparse.ArgumentTypeError(f"size {part!r} is not WIDTHxHEIGHT") from None
    return sizes


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m services.perception", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command")

    c = sub.add_parser("classify", help="print expression and feedback per frame of a video or per image")
    c.add_argument("path", help="a video file, an image, a folder of images, or mcap:LOG.mcap (a session's frames)")
    c.add_argument("--json", action="store_true", help="one JSON object per line")
    c.add_argument("--every", type=int, default=1, metavar="N", help="process every N-th frame only")
    _add_pipeline_args(c)

    b = sub.add_parser("bench", help="fps, capture-to-feedback latency and accuracy on the labelled clip")
    b.add_argument("--sizes", type=_parse_sizes, default=[(320, 240), (640, 480)],
                   help="frame sizes, e.g. 320x240,640x480 (default)")
    b.add_argument("--repeats", type=int, default=3, help="passes over the clip per row (default: 3)")
    b.add_argument("--no-naive", action="store_true", help="skip the naive full-frame Haar rows")
    b.add_argument("--all-cores", action="store_true", help="do not pin the process to one CPU")
    b.add_argument("--frame-step", type=int, default=1, metavar="N",
                   help="quick look: run the clip on every N-th frame only (default: all)")
    b.add_argument("--json", action="store_true")
    _add_pipeline_args(b)
    return parser


SUBCOMMANDS = ("classify", "bench")


def main(config):
    """The live service (``live.main``): ``main(PerceptionLiveConfig(...))``."""
    from .live import main as live_main

    return live_main(config)


def cli(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in SUBCOMMANDS:
        from .live import cli as live_cli

        return live_cli(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "classify":
            if args.every < 1:
                parser.error("--every must be >= 1")
            from .classify import classify

            classify(args.path, _pipeline_config(args), as_json=args.json, every=args.every)
            return 0
        if args.command == "bench":
            from .bench import run_bench

            run_bench(sizes=args.sizes, repeats=args.repeats, naive=not args.no_naive,
                      one_core=not args.all_cores, config=_pipeline_config(args), as_json=args.json,
                      frame_step=max(1, args.frame_step))
            return 0
    except (MediaError, AssetsMissingError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. piped into head
        return 0
    parser.print_help(sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(cli())
