"""Frame sources for the perception service: files and cameras through OpenCV. No transport here."""

from __future__ import annotations

import time
from typing import Iterator

import cv2

from common.perception.media import Frame, MediaError, iter_media, open_video

from .config import SourceSpec


def iter_camera(index: int, every: int = 1, clock=time.time) -> Iterator[Frame]:
    cap = cv2.VideoCapture(index)
    if not cap.isOpened():
        raise MediaError(f"camera:{index} cannot be opened (no such device, or no permission)")
    try:
        i = 0
        while True:
            ok, img = cap.read()
            t = clock()
            if not ok:
                raise MediaError(f"camera:{index} stopped delivering frames")
            if i % every == 0:
                yield Frame(i, t, img, f"camera:{index}")
            i += 1
    finally:
        cap.release()


def iter_video_realtime(path: str, every: int = 1, clock=time.time, sleep=time.sleep) -> Iterator[Frame]:
    """A video file paced at its frame rate and stamped with the wall clock, like a camera."""
    cap, fps = open_video(path)
    try:
        start = clock()
        i = 0
        while True:
            due = start + i / fps
            delay = due - clock()
            if delay > 0:
                sleep(delay)
            ok, img = cap.read()
            if not ok:
                return
            if i % every == 0:
                yield Frame(i, clock(), img, path)
            i += 1
    finally:
        cap.release()


def open_source(spec: SourceSpec, every: int = 1, realtime: bool = False) -> Iterator[Frame]:
    if spec.kind == "camera":
        return iter_camera(int(spec.target), every)
    if spec.kind == "mcap":
        # To add with the live service: read the `camera` key's common.protocol.CompressedImage records
        # (foxglove.CompressedImage) from the log, decode with cv2.imdecode, stamp with their timestamp.
        raise NotImplementedError(f"mcap:{spec.target}: replaying recorded camera frames is not built yet")
    if spec.kind == "video" and realtime:
        return iter_video_realtime(spec.target, every)
    return iter_media(spec.target, every)
