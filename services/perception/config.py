"""Configuration of the perception service, parsed only at the edge (the CLI).

The live service (a later addition: frames in, feedback published over Zenoh) will take a
``PerceptionServiceConfig``; ``classify`` and ``bench`` reuse its pipeline part.
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
      - ``mcap``:   frames recorded in an MCAP log, written ``mcap:LOG.mcap`` (replay; not built yet).
    """

    kind: str
    target: str

    @classmethod
    def parse(cls, text: str) -> "SourceSpec":
        if text.startswith("camera:"):
            index = text.split(":", 1)[1] or "0"
            if not index.isdigit():
                raise ValueError(f"camera source must be camera:N with N an integer, not {text!r}")
            return cls("camera", index)
        if text.startswith("mcap:"):
            return cls("mcap", text.split(":", 1)[1])
        from common.perception.media import is_image

        p = Path(text)
        if p.is_dir() or is_image(p):
            return cls("image", text)
        return cls("video", text)

    def __str__(self) -> str:
        return f"{self.kind}:{self.target}" if self.kind in ("camera", "mcap") else self.target


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
