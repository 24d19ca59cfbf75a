"""`python -m services.perception --source SOURCE`: the perception service over Zenoh.

A thin shell around the pure pipeline (``common.perception``): per frame it runs face detection, the
expression model and the reaction detector, and publishes

- the frame's ``ExpressionPrediction`` on ``hitl/<run>/perception/<camera>`` (congestion DROP),
- each debounced reaction as a ``Feedback`` (source ``face``, ``t_reaction`` = the capture time of the frame
  that triggered it) on ``hitl/<run>/feedback/<teacher_id>`` (BLOCK: never dropped),
- unless the frames come from Zenoh already, the frame as a JPEG ``foxglove.CompressedImage`` on
  ``hitl/<run>/camera/<camera>`` (DROP), so the recorder logs what the service saw.

Sources: a video file (paced at its frame rate and stamped with the wall clock unless ``--realtime false``),
an image or a folder, ``camera:N`` (stamped with the wall clock at capture), ``mcap:LOG.mcap`` (the camera
frames of a recorded session, stamped with their recorded capture times) and ``zenoh:CAMERA`` (frames another
process publishes, e.g. the face-video observer; stamped with their capture times). A frame whose bytes
cannot be decoded is counted (``frames_undecodable``) and skipped; a message that is not a valid
CompressedImage is counted by reason (``frames_dropped_<reason>``).

To the learner this service is a teacher: its service name is ``teacher.<teacher_id>`` and its final status
carries ``feedback_published``, which the learner waits for at the end of a run.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any
from collections.abc import Iterator

import cv2
import numpy as np

from common.perception.media import MediaError
from common.perception.pipeline import PerceptionPipeline
from common.perception.reaction import FeedbackEvent, FramePrediction
from common.protocol import (
    KEYS,
    Box,
    CompressedImage,
    ExpressionPrediction,
    Feedback,
    ProtocolError,
    Time,
    camera_key,
    feedback_key,
    perception_key,
)
from services.common.runtime import ServiceRuntime, wait_alive

from .config import PerceptionLiveConfig
from .sources import EncodedFrame, decode_image, iter_mcap_frames, open_source

FEEDBACK_SOURCE = "face"


def prediction_message(pred: FramePrediction) -> ExpressionPrediction:
    box = None
    if pred.box is not None:
        b = pred.box
        box = Box(max(0, int(b.x)), max(0, int(b.y)), max(0, int(b.w)), max(0, int(b.h)))
    probs = {}
    if pred.probs is not None:
        probs = {str(label)[:32]: min(1.0, max(0.0, float(p))) for label, p in list(zip(pred.labels, pred.probs))[:16]}
    return ExpressionPrediction(
        t_capture=max(0.0, float(pred.t_capture)),
        frame=int(pred.index),
        box=box,
        label=(pred.label or "")[:32],
        confidence=min(1.0, max(0.0, pred.confidence)),
        probabilities=probs,
    )


def feedback_message(
    run: str, teacher_id: str, seq: int, event: FeedbackEvent, screen=None, span: float = 4.0
) -> Feedback:
    """The Feedback of one reaction; with the `screen` (a ScreenTimeline) the person watched, the steps it
    showed in the `span` s before the triggering frame."""
    t = max(0.0, float(event.t_capture))
    actor, shown = screen.window(t, span) if screen is not None else (None, [])
    return Feedback(
        run=run,
        teacher_id=teacher_id,
        seq=seq,
        t_reaction=t,
        value=int(event.value),
        source=FEEDBACK_SOURCE,
        actor=actor,
        shown=shown if actor is not None else None,
    )


def encode_jpeg(image: np.ndarray, quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def image_message(data: bytes, t_capture: float, camera: str, fmt: str = "jpeg") -> CompressedImage:
    return CompressedImage(timestamp=Time.from_seconds(max(0.0, t_capture)), frame_id=camera, data=data, format=fmt)


class PerceptionService:
    """The per-frame work and the publishing, given a session (no loop, no source)."""

    def __init__(self, config: PerceptionLiveConfig, rt: ServiceRuntime, session: Any, pipeline: PerceptionPipeline):
        from common.wire.transport import MessagePublisher

        self.config, self.rt, self.session, self.pipeline = config, rt, session, pipeline
        self.feedback = MessagePublisher(session, feedback_key(config.run, config.teacher_id))
        self._predictions: dict[str, Any] = {}
        self._frames: dict[str, Any] = {}
        self.feedback_seq = 0
        self.progress = None
        if config.state_file:  # a restart continues the seq (receivers drop what they have seen)
            from services.common.progress import ProgressFile

            self.progress = ProgressFile(config.state_file)
            state = self.progress.read()
            if state:
                self.feedback_seq = int(state["next_seq"])
                rt.counters["feedback_published"] = self.feedback_seq
        self.screens: dict[str, Any] = {}  # screen (person) -> ScreenTimeline, from the console's Shown messages
        self.screen: str | None = None  # the screen of the frame being processed (its frame_id)
        self.t_first: float | None = None  # monotonic time of the first and last processed frame
        self.t_last = 0.0
        self.cpu_first = 0.0

    def _publisher(self, table: dict, key: str) -> Any:
        from common.wire.transport import MessagePublisher

        pub = table.get(key)
        if pub is None:
            pub = table[key] = MessagePublisher(self.session, key)
        return pub

    def publish_frame(self, data: bytes, t_capture: float, camera: str, fmt: str = "jpeg") -> None:
        self._publisher(self._frames, camera_key(self.config.run, camera)).put(
            image_message(data, t_capture, camera, fmt)
        )
        self.rt.counters["frames_published"] += 1

    def process(
        self, image: np.ndarray, index: int, t_capture: float, camera: str, live_clock: bool
    ) -> FeedbackEvent | None:
        t0 = time.perf_counter()
        if self.t_first is None:
            self.t_first, self.cpu_first = time.monotonic(), time.process_time()
        pred, event = self.pipeline.process(image, index, t_capture)
        self.rt.samples["process_s"].append(time.perf_counter() - t0)
        self.t_last = time.monotonic()
        c = self.rt.counters
        c["frames_processed"] += 1
        c["frames_with_face"] += pred.box is not None
        try:
            self._publisher(self._predictions, perception_key(self.config.run, camera)).put(prediction_message(pred))
            c["predictions_published"] += 1
        except ProtocolError as e:  # never expected; a prediction must not take the service down
            c[f"predictions_invalid_{e.reason}"] += 1
        if event is not None:
            seq = self.feedback_seq
            if self.progress:  # first: a crash right after must not reuse this seq
                self.progress.write({"next_seq": seq + 1})
            self.feedback.put(
                feedback_message(
                    self.config.run,
                    self.config.teacher_id,
                    seq,
                    event,
                    self.screens.get(self.screen),
                    self.config.screen_span,
                )
            )
            self.feedback_seq = seq + 1
            c["feedback_published"] = self.feedback_seq
            c["feedback_positive" if event.value > 0 else "feedback_negative"] += 1
            if live_clock:  # capture of the triggering frame -> published (queue + decode + pipeline)
                self.rt.samples["capture_to_feedback_s"].append(time.time() - t_capture)
        return event

    def process_encoded(self, frame: EncodedFrame, live_clock: bool) -> FeedbackEvent | None:
        """A compressed frame (from Zenoh or a log): decode, count it if it cannot be, process otherwise."""
        if frame.data is None:
            self.rt.counters[f"frames_dropped_{frame.error or 'malformed'}"] += 1
            return None
        image = decode_image(frame.data)
        if image is None:
            self.rt.counters["frames_undecodable"] += 1
            if self.rt.counters["frames_undecodable"] == 1:
                self.rt.event(
                    f"frame {frame.index} of camera {frame.camera}: the image bytes cannot be decoded; "
                    f"dropped (counted as frames_undecodable)",
                    level=3,
                )
            return None
        return self.process(image, frame.index, frame.t_capture, frame.camera, live_clock)

    def on_shown(self, items) -> None:
        """Paint reports of the people's screens (console `Shown` messages)."""
        from common.core.screen import ScreenTimeline

        for item in items:
            try:
                msg = item.decode()
            except ProtocolError as e:
                self.rt.counters[f"shown_dropped_{e.reason}"] += 1
                continue
            self.screens.setdefault(msg.screen, ScreenTimeline()).add(msg.actor, msg.seq, msg.t_shown)

    def throughput(self) -> dict[str, float]:
        """Frames processed per wall second and CPU ms per frame (the whole process: decode, pipeline,
        publishing), from the first processed frame to the last."""
        n = self.rt.counters["frames_processed"]
        if self.t_first is None or n < 2:
            return {}
        wall = max(1e-9, self.t_last - self.t_first)
        cpu = time.process_time() - self.cpu_first
        return {
            "frames": n,
            "wall_s": round(wall, 3),
            "fps": round((n - 1) / wall, 2),
            "cpu_ms_per_frame": round(1e3 * cpu / n, 3),
        }

    def close(self) -> None:
        for pub in (self.feedback, *self._predictions.values(), *self._frames.values()):
            pub.close()


def _stills(spec) -> bool:
    return spec.kind == "image"


def _file_frames(config: PerceptionLiveConfig) -> Iterator[tuple[np.ndarray, int, float, bool]]:
    """(image, index, t_capture, stamped by the wall clock) for video, image, camera sources."""
    spec = config.source_spec
    for frame in open_source(spec, config.every, config.realtime):
        if _stills(spec):
            yield frame.image, frame.index, time.time(), True
        else:
            yield frame.image, frame.index, frame.t_capture, spec.kind == "camera" or config.realtime


def main(config: PerceptionLiveConfig) -> int:
    """Run the service until the source ends, ``stop_with`` services have stopped, or SIGTERM/SIGINT."""
    import dataclasses

    from common.wire.transport import subscription

    spec = config.source_spec
    if spec.kind in ("video", "image", "mcap") and not os.path.exists(spec.target):
        raise MediaError(f"{spec.target}: no such file or directory")
    pipeline_config = config.pipeline
    if _stills(spec):  # each image alone: no smoothing across unrelated pictures (as `classify`)
        pipeline_config = dataclasses.replace(
            pipeline_config, reaction=dataclasses.replace(pipeline_config.reaction, tau_s=0.0)
        )
    pipeline = PerceptionPipeline.from_config(pipeline_config)  # a missing model fails here, before joining
    rt = ServiceRuntime(config.service_name, config)
    rt.set_counters_source(lambda: {"feedback_published": svc.feedback_seq if svc is not None else 0})
    svc: PerceptionService | None = None
    processed = 0
    code = 0
    with rt.session() as session:
        svc = PerceptionService(config, rt, session, pipeline)
        try:
            if spec.kind == "zenoh":
                with (
                    subscription(
                        session, camera_key(config.run, spec.target), maxsize=config.queue, policy="drop_oldest"
                    ) as frames,
                    subscription(
                        session, KEYS["status"].wildcard(config.run), maxsize=256, policy="drop_oldest"
                    ) as status,
                    subscription(
                        session, KEYS["shown"].wildcard(config.run), maxsize=1024, policy="drop_oldest"
                    ) as shown,
                ):
                    rt.ready()
                    processed = _run_zenoh(
                        config, rt, svc, frames, status, spec.target, shown if config.screens else None
                    )
                    rt.counters.update({f"inbox_{k}": v for k, v in frames.snapshot().items()})
            else:
                rt.ready()
                missing = wait_alive(session, config.run, config.wait_for, config.start_timeout, rt.stop)
                if missing and not rt.stop.is_set():
                    rt.log(f"gave up waiting for {sorted(missing)} after {config.start_timeout} s")
                    return 3
                processed = _run_iterator(config, rt, svc, spec)
        finally:
            svc.close()
    tp = svc.throughput()
    rt.write_stats(throughput=tp)
    rate = (
        f" in {tp['wall_s']:.1f} s ({tp['fps']:.1f} fps, {tp['cpu_ms_per_frame']:.1f} ms CPU per frame)" if tp else ""
    )
    rt.log(
        f"stopped: {processed} frames processed{rate}, {svc.feedback_seq} feedback published "
        f"({rt.counters['feedback_positive']} +1, {rt.counters['feedback_negative']} -1)"
    )
    return code


def _run_iterator(config: PerceptionLiveConfig, rt: ServiceRuntime, svc: PerceptionService, spec) -> int:
    processed = 0
    if spec.kind == "mcap":
        for n, ef in enumerate(iter_mcap_frames(spec.target, realtime=config.realtime)):
            if rt.stop.is_set():
                break
            if n % config.every:
                continue
            if config.publish_frames and ef.data is not None:
                svc.publish_frame(ef.data, ef.t_capture, ef.camera)
            svc.process_encoded(ef, live_clock=False)
            processed += 1
            rt.tick()
            if config.max_frames is not None and processed >= config.max_frames:
                break
        return processed
    stills = _stills(spec)
    for image, index, t_capture, live_clock in _file_frames(config):
        if rt.stop.is_set():
            break
        if stills:
            svc.pipeline.reset()
        if config.publish_frames:
            svc.publish_frame(encode_jpeg(image, config.jpeg_quality), t_capture, config.camera)
        svc.process(image, index, t_capture, config.camera, live_clock)
        processed += 1
        rt.tick()
        if config.max_frames is not None and processed >= config.max_frames:
            break
    return processed


def _run_zenoh(
    config: PerceptionLiveConfig, rt: ServiceRuntime, svc: PerceptionService, frames, status, camera: str, shown=None
) -> int:
    stopped: set[str] = set()
    waiting = set(config.stop_with)
    index = processed = 0
    last_frame = time.monotonic()
    while not rt.stop.is_set():
        item = frames.get(timeout=0.05)
        if item is not None:
            last_frame = time.monotonic()
            try:
                msg = item.decode()
            except ProtocolError as e:
                ef = EncodedFrame(index, 0.0, None, camera, e.reason)
            else:
                ef = EncodedFrame(index, msg.timestamp.to_seconds(), msg.data, camera)
                svc.screen = msg.frame_id
            if shown is not None:
                svc.on_shown(shown.drain())
            index += 1
            rt.counters["frames_received"] += 1
            if ef.index % config.every == 0:
                svc.process_encoded(ef, live_clock=True)
                processed += 1
            if config.max_frames is not None and processed >= config.max_frames:
                break
        for st_item in status.drain():
            try:
                st = st_item.decode()
            except ProtocolError:
                continue
            if st.state == "stopped" and st.service in waiting:
                stopped.add(st.service)
        if waiting and waiting <= stopped and len(frames) == 0 and time.monotonic() - last_frame >= config.idle_stop:
            break
        rt.tick()
    return processed


def cli(argv: list[str] | None = None) -> int:
    from common.config import parse_config
    from common.perception.assets import AssetsMissingError

    config = parse_config(
        PerceptionLiveConfig,
        argv,
        prog="python -m services.perception",
        description=(PerceptionLiveConfig.__doc__ or "").strip()
        + "\n\nAlso: python -m services.perception classify|bench --help (offline).",
    )
    try:
        return main(config)
    except (MediaError, AssetsMissingError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        if type(exc).__name__ != "ZError":
            raise
        print(f"error: cannot reach the Zenoh router at {', '.join(config.connect)}: {exc}", file=sys.stderr)
        return 2
