"""Frame sources for the perception service: files and cameras through OpenCV, recorded sessions (MCAP).
No Zenoh here (the live service subscribes to ``zenoh:CAMERA`` itself)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from collections.abc import Callable, Iterator

import cv2
import numpy as np

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


def decode_image(data: bytes) -> np.ndarray | None:
    """JPEG/PNG/WebP bytes -> BGR image, or None when OpenCV cannot decode them (a malformed frame)."""
    if not data:
        return None
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


@dataclass(frozen=True)
class EncodedFrame:
    """A compressed camera frame as recorded or received: its capture time and bytes (None when the record
    was not a valid CompressedImage)."""

    index: int
    t_capture: float
    data: bytes | None
    camera: str
    error: str | None = None


def iter_mcap_frames(
    path: str, camera: str | None = None, realtime: bool = False, clock=time.time, sleep=time.sleep
) -> Iterator[EncodedFrame]:
    """The camera frames (CompressedImage on ``hitl/<run>/camera/<id>``) of a recorded session, in log order,
    stamped with their recorded capture time. ``camera`` picks one camera (default: every camera). With
    ``realtime`` they are paced by their capture times. A log without camera frames raises ``MediaError``."""
    import os
    import warnings

    from common.logs.mcap_log import LogRecoveryWarning, read_log
    from common.protocol import CompressedImage

    if not os.path.exists(path):
        raise MediaError(f"{path}: no such file or directory")
    index = 0
    t0: tuple[float, float] | None = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogRecoveryWarning)
        try:
            for rec in read_log(path):
                parts = rec.key.split("/")
                if len(parts) != 4 or parts[2] != "camera" or (camera is not None and parts[3] != camera):
                    continue
                msg = rec.message
                if not isinstance(msg, CompressedImage):
                    yield EncodedFrame(
                        index,
                        rec.log_time * 1e-9,
                        None,
                        parts[3],
                        rec.error.reason if rec.error is not None else "not_an_image",
                    )
                    index += 1
                    continue
                t = msg.timestamp.to_seconds()
                if realtime:
                    if t0 is None:
                        t0 = (clock(), t)
                    delay = t0[0] + (t - t0[1]) - clock()
                    if delay > 0:
                        sleep(delay)
                yield EncodedFrame(index, t, msg.data, parts[3])
                index += 1
        except (OSError, ValueError) as exc:
            if index == 0:
                raise MediaError(f"{path}: cannot read this as a session log ({exc})") from None
            raise
    if index == 0:
        raise MediaError(f"{path}: the log holds no camera frames" + (f" from camera {camera!r}" if camera else ""))


def iter_mcap(
    path: str, every: int = 1, realtime: bool = False, on_bad: Callable[[EncodedFrame], None] | None = None
) -> Iterator[Frame]:
    """Decoded frames of a recorded session (see ``iter_mcap_frames``); undecodable ones go to ``on_bad``."""
    for i, ef in enumerate(iter_mcap_frames(path, realtime=realtime)):
        if i % every:
            continue
        img = decode_image(ef.data) if ef.data is not None else None
        if img is None:
            if on_bad is not None:
                on_bad(ef)
            continue
        yield Frame(ef.index, ef.t_capture, img, f"mcap:{ef.camera}")


def open_source(spec: SourceSpec, every: int = 1, realtime: bool = False) -> Iterator[Frame]:
    if spec.kind == "camera":
        return iter_camera(int(spec.target), every)
    if spec.kind == "mcap":
        return iter_mcap(spec.target, every, realtime)
    if spec.kind == "zenoh":
        raise ValueError(
            f"{spec}: frames from Zenoh are read by the live service (python -m services.perception "
            f"--source {spec} --connect ... --run ...)"
        )
    if spec.kind == "video" and realtime:
        return iter_video_realtime(spec.target, every)
    return iter_media(spec.target, every)
