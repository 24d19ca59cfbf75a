"""Face detection: OpenCV 4.x Haar cascade, largest face, made cheap enough for 30 fps on one core.

Full-frame Haar detection at 320x240 costs about 20-25 ms on one core here, and grows with the frame.
Two measures bring it down while keeping the classifier's accuracy (see ``docs/perception.md``):

1. ``HaarFaceDetector`` detects on a grey copy downscaled to ``detect_width`` pixels (160 by default)
   and ignores faces narrower than ``min_face_frac`` of the frame, so its cost barely depends on the
   camera resolution.
2. ``TrackingFaceDetector`` runs that full-frame search only every ``redetect_every`` frames (or when
   the face is lost); in between it searches a small region around the last box, over a narrow range
   of scales, at the same pixel scale as the full search. (Searching the region at another scale
   gave boxes a few per cent larger or smaller, which compounds from frame to frame, and the
   classifier is sensitive to the crop size: 90% instead of 98% on the labelled clip.)

Both are deterministic: the same frames in the same order give the same boxes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np


@dataclass(frozen=True)
class FaceBox:
    """Axis-aligned face box in pixels of the frame it was found in."""

    x: int
    y: int
    w: int
    h: int

    @property
    def area(self) -> int:
        return self.w * self.h

    def as_list(self) -> list[int]:
        return [self.x, self.y, self.w, self.h]


class FaceDetector(Protocol):
    """Largest face in a grey (uint8, HxW) frame, or None. May keep state between calls (tracking)."""

    def detect(self, gray: np.ndarray) -> FaceBox | None: ...

    def reset(self) -> None: ...


def cascade_path(name: str) -> str:
    """A cascade file name from ``cv2.data.haarcascades`` (OpenCV 4.x wheels ship them) or a path."""
    if Path(name).is_file():
        return str(name)
    base = getattr(getattr(cv2, "data", None), "haarcascades", None)
    if base is None:
        raise FileNotFoundError(
            "this OpenCV build ships no Haar cascades (cv2.data.haarcascades is missing); "
            "install opencv-python-headless>=4.10,<5 as pyproject.toml pins it"
        )
    path = Path(base) / name
    if not path.is_file():
        raise FileNotFoundError(f"Haar cascade {name} not found in {base}")
    return str(path)


def load_cascade(name: str) -> cv2.CascadeClassifier:
    casc = cv2.CascadeClassifier(cascade_path(name))
    if casc.empty():
        raise RuntimeError(f"OpenCV could not load the cascade {name}")
    return casc


def _largest(rects, scale: float, dx: int = 0, dy: int = 0) -> FaceBox | None:
    if rects is None or len(rects) == 0:
        return None
    x, y, w, h = max((tuple(r) for r in rects), key=lambda r: (r[2] * r[3], -r[0], -r[1]))
    return FaceBox(int(round(x * scale)) + dx, int(round(y * scale)) + dy, int(round(w * scale)), int(round(h * scale)))


@dataclass(frozen=True)
class HaarConfig:
    """Full-frame Haar search. ``detect_width`` 0 means detect at the frame's own size (the naive way)."""

    cascade: str = "haarcascade_frontalface_default.xml"
    detect_width: int = 160
    scale_factor: float = 1.1
    min_neighbors: int = 5
    min_face_frac: float = 0.12  # faces narrower than this fraction of the frame width are ignored
    min_face_px: int = 24  # ... and never below the cascade's 24-px window in the image searched


class HaarFaceDetector:
    """Stateless full-frame Haar detection on a downscaled grey copy; returns the largest face."""

    def __init__(self, config: HaarConfig = HaarConfig()) -> None:
        self.config = config
        self.cascade = load_cascade(config.cascade)

    def reset(self) -> None:
        pass

    def detect(self, gray: np.ndarray) -> FaceBox | None:
        c = self.config
        h, w = gray.shape[:2]
        if c.detect_width and w > c.detect_width:
            scale = w / c.detect_width
            small = cv2.resize(gray, (c.detect_width, max(1, int(round(h / scale)))), interpolation=cv2.INTER_AREA)
        else:
            scale, small = 1.0, gray
        min_px = max(c.min_face_px, int(c.min_face_frac * small.shape[1]))
        rects = self.cascade.detectMultiScale(
            small, scaleFactor=c.scale_factor, minNeighbors=c.min_neighbors, minSize=(min_px, min_px)
        )
        return _largest(rects, scale)


@dataclass(frozen=True)
class TrackingConfig:
    """Re-detect in a region around the last face; full-frame search every ``redetect_every`` frames."""

    redetect_every: int = 15
    roi_expand: float = 0.5  # the search region extends this fraction of the box size on each side
    roi_face_px: int | None = None  # the region is rescaled so the last face is about this wide;
    # None: searched at the full detector's own scale (same box geometry as a full search), within
    # roi_face_px_range
    roi_face_px_range: tuple[int, int] = (40, 96)
    roi_scale_range: float = 1.25  # faces from roi_face_px/range to roi_face_px*range are searched
    scale_factor: float = 1.1
    min_neighbors: int = 4


class TrackingFaceDetector:
    """Full-frame detection (via ``full``) plus a cheap local search between full searches."""

    def __init__(self, full: HaarFaceDetector | None = None, config: TrackingConfig = TrackingConfig()) -> None:
        self.full = full or HaarFaceDetector()
        self.config = config
        self.cascade = self.full.cascade
        self.reset()

    def reset(self) -> None:
        self.last: FaceBox | None = None
        self.since_full = 0

    def _local(self, gray: np.ndarray, box: FaceBox) -> FaceBox | None:
        c = self.config
        H, W = gray.shape[:2]
        side = max(box.w, box.h)
        m = int(round(c.roi_expand * side))
        x1, y1 = max(0, box.x - m), max(0, box.y - m)
        x2, y2 = min(W, box.x + box.w + m), min(H, box.y + box.h + m)
        if x2 - x1 < 8 or y2 - y1 < 8:
            return None
        if c.roi_face_px is not None:
            target = c.roi_face_px
        else:
            dw = self.full.config.detect_width
            full_scale = max(1.0, W / dw) if dw else 1.0
            target = min(max(side / full_scale, c.roi_face_px_range[0]), c.roi_face_px_range[1])
        scale = side / target  # roi pixels per searched pixel
        roi = gray[y1:y2, x1:x2]
        if scale > 1.0:
            roi = cv2.resize(
                roi,
                (max(1, int(round((x2 - x1) / scale))), max(1, int(round((y2 - y1) / scale)))),
                interpolation=cv2.INTER_AREA,
            )
        else:
            scale = 1.0
        fp = side / scale
        lo = max(12, int(fp / c.roi_scale_range))
        hi = max(lo + 1, int(fp * c.roi_scale_range))
        rects = self.cascade.detectMultiScale(
            roi, scaleFactor=c.scale_factor, minNeighbors=c.min_neighbors, minSize=(lo, lo), maxSize=(hi, hi)
        )
        return _largest(rects, scale, x1, y1)

    def detect(self, gray: np.ndarray) -> FaceBox | None:
        box = None
        if self.last is not None and self.since_full < self.config.redetect_every:
            box = self._local(gray, self.last)
            self.since_full += 1
        if box is None:
            box = self.full.detect(gray)
            self.since_full = 0
        self.last = box
        return box


def make_detector(kind: str = "tracking", detect_width: int = 160) -> FaceDetector:
    """``tracking`` (default), ``haar`` (downscaled, every frame) or ``haar-full`` (naive full-frame)."""
    if kind == "tracking":
        return TrackingFaceDetector(HaarFaceDetector(HaarConfig(detect_width=detect_width)))
    if kind == "haar":
        return HaarFaceDetector(HaarConfig(detect_width=detect_width))
    if kind == "haar-full":
        # fer's own defaults: native resolution, scale 1.1, 5 neighbours, faces >= 50 px.
        return HaarFaceDetector(HaarConfig(detect_width=0, min_face_frac=0.0, min_face_px=50))
    raise ValueError(f"unknown face detector {kind!r}: tracking, haar or haar-full")
