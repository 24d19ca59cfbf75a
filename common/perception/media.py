"""Reading frames from image and video files (OpenCV), with friendly errors. No transport here."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from collections.abc import Iterator

import cv2
import numpy as np

IMAGE_EXTS = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff", ".pgm", ".ppm"})
VIDEO_EXTS = frozenset({".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv"})
DEFAULT_FPS = 30.0


class MediaError(ValueError):
    """A path that is missing, of an unknown kind, or that OpenCV cannot decode."""


@dataclass(frozen=True)
class Frame:
    index: int
    t_capture: float  # seconds: index / fps for files; the camera's clock for live sources
    image: np.ndarray  # BGR uint8 (or grey)
    source: str = ""


def is_image(path: Path) -> bool:
    return Path(path).suffix.lower() in IMAGE_EXTS


def is_video(path: Path) -> bool:
    return Path(path).suffix.lower() in VIDEO_EXTS


def read_image(path: str | Path) -> np.ndarray:
    path = Path(path)
    if not path.exists():
        raise MediaError(f"{path}: no such file")
    if path.is_dir():
        raise MediaError(f"{path} is a directory")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise MediaError(f"{path}: OpenCV cannot read this as an image")
    return img


def open_video(path: str | Path) -> tuple[cv2.VideoCapture, float]:
    path = Path(path)
    if not path.exists():
        raise MediaError(f"{path}: no such file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise MediaError(f"{path}: OpenCV cannot open this as a video")
    fps = cap.get(cv2.CAP_PROP_FPS)
    if not fps or not np.isfinite(fps) or fps <= 0 or fps > 1000:
        fps = DEFAULT_FPS
    return cap, float(fps)


def iter_video(path: str | Path, every: int = 1, max_frames: int | None = None) -> Iterator[Frame]:
    """Decoded frames (every ``every``-th, by original index), stamped index / fps."""
    if every < 1:
        raise ValueError("every must be >= 1")
    cap, fps = open_video(path)
    try:
        index = 0
        yielded = 0
        ok, img = cap.read()
        if not ok:
            raise MediaError(f"{path}: no frame could be decoded")
        while ok:
            if index % every == 0:
                yield Frame(index, index / fps, img, str(path))
                yielded += 1
                if max_frames is not None and yielded >= max_frames:
                    break
            index += 1
            ok, img = cap.read()
    finally:
        cap.release()


def load_video(path: str | Path) -> tuple[list[np.ndarray], float]:
    cap, fps = open_video(path)
    frames = []
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            frames.append(img)
    finally:
        cap.release()
    if not frames:
        raise MediaError(f"{path}: no frame could be decoded")
    return frames, fps


def iter_media(path: str | Path, every: int = 1) -> Iterator[Frame]:
    """Frames of a video, one frame for an image, or each image of a folder (sorted, index = position)."""
    path = Path(path)
    if not path.exists():
        raise MediaError(f"{path}: no such file or directory")
    if path.is_dir():
        images = sorted(p for p in path.iterdir() if is_image(p))
        if not images:
            raise MediaError(f"{path}: the folder holds no image ({', '.join(sorted(IMAGE_EXTS))})")
        for i, p in enumerate(images):
            if i % every == 0:
                yield Frame(i, 0.0, read_image(p), str(p))
        return
    if is_image(path):
        yield Frame(0, 0.0, read_image(path), str(path))
        return
    if is_video(path) or path.suffix == "":
        yield from iter_video(path, every)
        return
    # Unknown extension: try as image, then as video.
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is not None:
        yield Frame(0, 0.0, img, str(path))
        return
    yield from iter_video(path, every)


def letterbox(image: np.ndarray, width: int, height: int, fill: int = 0) -> np.ndarray:
    """Scale to fit ``width`` x ``height`` keeping the aspect ratio; pad the rest with ``fill``."""
    h, w = image.shape[:2]
    s = min(width / w, height / h)
    nw, nh = max(1, int(round(w * s))), max(1, int(round(h * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(image, (nw, nh), interpolation=interp)
    out = np.full((height, width) + image.shape[2:], fill, dtype=image.dtype)
    y, x = (height - nh) // 2, (width - nw) // 2
    out[y : y + nh, x : x + nw] = resized
    return out
