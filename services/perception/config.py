"""Configuration of the perception service, parsed only at the edge (the CLI).

``PerceptionLiveConfig`` is the live service's documented config and command line
(``python -m services.perception --source ...``); ``PerceptionServiceConfig`` is the pure part (a source
and the pipeline) that ``run_pipeline`` and the offline subcommands use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from common.perception.pipeline import PipelineConfig


@dataclass(frozen=True)
class SourceSpec:
    """Where frames come from.

    ``kind`` is one of:
      - ``video``:  a video file (frames stamped index / fps, or paced in real time with ``realtime``);
      - ``image``:  one still image, or a folder of images (each judged alone);
      - ``camera``: an OpenCV camera index, written ``camera:0`` (frames stamped with the wall clock
                    at capture);
      - ``mcap``:   the camera frames (``foxglove.CompressedImage``) a recorded session holds, written
                    ``mcap:LOG.mcap`` (or ``mcap:RUN_DIR``); stamped with their recorded capture times;
      - ``zenoh``:  frames another process publishes on ``hitl/<run>/camera/CAMERA``, written ``zenoh:CAMERA``
                    (live service only), stamped with their capture times.
    """

    kind: str
    target: str

    @classmethod
    def parse(cls, text: str) -> SourceSpec:
        if text.startswith("camera:"):
            index = text.split(":", 1)[1] or "0"
            if not index.isdigit():
                raise ValueError(f"camera source must be camera:N with N an integer, not {text!r}")
            return cls("camera", index)
        if text.startswith("mcap:"):
            return cls("mcap", text.split(":", 1)[1])
        if text.startswith("zenoh:"):
            from common.protocol import validate_name

            camera = text.split(":", 1)[1]
            try:
                validate_name(camera, "camera")
            except Exception as exc:
                raise ValueError(f"zenoh source must be zenoh:CAMERA with a valid camera id: {exc}") from None
            return cls("zenoh", camera)
        from common.perception.media import is_image

        p = Path(text)
        if p.is_dir() or is_image(p):
            return cls("image", text)
        return cls("video", text)

    def __str__(self) -> str:
        return f"{self.kind}:{self.target}" if self.kind in ("camera", "mcap", "zenoh") else self.target


@dataclass(frozen=True)
class PerceptionServiceConfig:
    """Everything the perception service needs; logged with a run.

    source:     frames to watch (see ``SourceSpec``): a video path, an image or folder, ``camera:0`` or
                ``mcap:LOG.mcap``.
    every:      process every N-th frame only (1 = all).
    realtime:   pace a video file at its own frame rate and stamp frames with the wall clock, as a
                camera would (False: as fast as possible, stamped index / fps).
    max_frames: stop after this many processed frames (None = until the source ends).
    pipeline:   face detector, expression model and reaction (smoothing/hysteresis) settings.
    """

    source: str = "camera:0"
    every: int = 1
    realtime: bool = False
    max_frames: int | None = None
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)

    @property
    def source_spec(self) -> SourceSpec:
        return SourceSpec.parse(self.source)


# -- the live service ----------------------------------------------------------------------------------------

import math  # noqa: E402

from common.config import option  # noqa: E402
from common.protocol import teacher_service_name  # noqa: E402
from services.common.config import ServiceConfig, _check_name  # noqa: E402

DETECTORS = ("tracking", "haar", "haar-full")


@dataclass(frozen=True)
class PerceptionLiveConfig(ServiceConfig):
    """The perception service: frames in, per-frame expression and debounced +1/-1 Feedback out, over Zenoh.

    Publishes every processed frame's ExpressionPrediction on hitl/<run>/perception/<camera> (congestion
    DROP), each feedback event as a Feedback (source `face`, stamped with the capture time of the frame that
    triggered it) on hitl/<run>/feedback/<teacher_id> (BLOCK), and, unless the frames already come from
    Zenoh, the frames themselves as JPEG foxglove.CompressedImage on hitl/<run>/camera/<camera> (DROP).
    To the learner this service is a teacher: its service name is teacher.<teacher_id>.
    Offline subcommands: `python -m services.perception classify --help`, `... bench --help`."""

    source: str = option(
        "",
        "frames: a video file, an image or a folder of images, camera:N, mcap:LOG.mcap "
        "(re-run perception on a recorded session's camera frames), or zenoh:CAMERA (frames "
        "published on hitl/<run>/camera/CAMERA, e.g. by the face-video observer)",
    )
    teacher_id: str = option("face", "teacher name: Feedback goes to hitl/<run>/feedback/<teacher_id>")
    camera: str = option(
        "cam0", "camera id of the published frames and predictions (zenoh:CAMERA and mcap sources keep their own)"
    )
    publish_frames: bool = option(
        True,
        "publish the frames as JPEG CompressedImage (never for zenoh: sources, whose frames are on the bus already)",
    )
    jpeg_quality: int = option(80, "JPEG quality of published frames")
    realtime: bool = option(
        True,
        "video files: pace at the file's frame rate and stamp frames with the wall clock, "
        "as a camera (false: as fast as possible, stamped index / fps); mcap: pace by "
        "the recorded capture times (false: as fast as possible)",
    )
    every: int = option(1, "process every N-th frame only")
    max_frames: int | None = option(None, "stop after this many processed frames (none = until the source ends)")
    queue: int = option(4, "zenoh: sources: frames waiting beyond this many are dropped, oldest first (counted)")
    stop_with: tuple[str, ...] = option(
        (),
        "zenoh: sources: stop once these services have reported 'stopped' and "
        "no frame has come for idle-stop s (empty: run until SIGTERM)",
    )
    idle_stop: float = option(0.5, "see stop-with (s)")
    screens: bool = option(
        False,
        "zenoh: sources from the console: a frame's frame_id names the person's screen; "
        "each Feedback lists the steps that screen showed (hitl/<run>/shown/<screen>) in "
        "the screen-span s before the frame, so the learner credits it in seconds",
    )
    screen_span: float = option(4.0, "see screens (s): the longest delay the learner assumes")
    wait_for: tuple[str, ...] = option((), "services that must be alive before the first frame (e.g. recorder)")
    start_timeout: float = option(60.0, "seconds to wait for those services")
    state_file: str | None = option(
        None,
        "progress file (the next Feedback seq), rewritten before each Feedback, so "
        "a restarted service continues the seq instead of repeating it",
    )
    model: str = option(
        "mini-xception", "mini-xception, haar-smile, or a model config .json/.toml (docs/perception.md)"
    )
    detector: str = option("tracking", "face detector", choices=DETECTORS)
    detect_width: int = option(160, "width of the copy the full face search runs on")

    def __post_init__(self):
        super().__post_init__()
        if not self.source:
            raise ValueError(
                "--source is required: a video file, an image or folder, camera:N, mcap:LOG.mcap or zenoh:CAMERA"
            )
        SourceSpec.parse(self.source)  # raises ValueError for a malformed camera:/zenoh: source
        _check_name(self.teacher_id, "teacher-id")
        _check_name(self.camera, "camera")
        for name in (*self.stop_with, *self.wait_for):
            _check_name(name, "service")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg-quality must be in 1..100, got {self.jpeg_quality}")
        if self.every < 1:
            raise ValueError(f"every must be >= 1, got {self.every}")
        if self.queue < 1:
            raise ValueError(f"queue must be >= 1, got {self.queue}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max-frames must be >= 1 or none, got {self.max_frames}")
        for name in ("idle_stop", "start_timeout"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {v}")
        if self.detector not in DETECTORS:
            raise ValueError(f"detector must be one of {DETECTORS}, got {self.detector!r}")

    @property
    def source_spec(self) -> SourceSpec:
        return SourceSpec.parse(self.source)

    @property
    def service_name(self) -> str:
        return teacher_service_name(self.teacher_id)

    @property
    def pipeline(self) -> PipelineConfig:
        return PipelineConfig(detector=self.detector, detect_width=self.detect_width, model=self.model)
