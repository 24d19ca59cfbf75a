"""The face-video teacher's pure parts: scheduling reactions as clips, the assumed delay that accounts for the
perception lag, matching perceived feedback to shown reactions, the launcher defaults, the protocol message."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from common.core.credit import credit_weights
from common.core.delay import DelayModel
from common.protocol import Feedback, ObserverReaction, ProtocolError, decode, reaction_key
from services.teacher.face_metrics import face_metrics
from services.teacher.face_launch import PERCEPTION_LAG_S, face_assumed_delay, face_video_defaults
from services.teacher.face_video import ClipLibrary, FaceVideoConfig, FaceVideoCore

FPS = 24.0


def tiny_library() -> ClipLibrary:
    frames = {i: bytes([i % 256]) for i in range(0, 60)}
    return ClipLibrary(frames, {1: range(30, 60), -1: range(0, 30)}, b"blank", FPS, (4, 4))


def step(seq: int, t: float, good: bool, episode: int = 0):
    from common.protocol import Step

    d0 = 5.0
    return Step(
        run="r",
        incarnation="a1",
        seq=seq,
        t_action=t,
        episode=episode,
        t_in_episode=seq,
        obs=[0.0],
        action=0,
        reward=-0.01,
        next_obs=[0.0],
        terminated=False,
        truncated=False,
        weights_version=0,
        info={"target_distance_before": d0, "target_distance_after": d0 - 1 if good else d0 + 1},
    )


def play(core: FaceVideoCore, steps, until: float, t0: float = 100.0):
    """Feed steps at their times and tick the camera at FPS; returns (tick time, frame) and the reactions shown."""
    frames, shown = [], []
    pending = sorted(steps, key=lambda s: s.t_action)
    t = t0
    while t < until:
        while pending and pending[0].t_action <= t:
            core.on_step(pending.pop(0))
        idx, done = core.frame(t)
        frames.append((t, idx))
        shown += done
        t += 1.0 / FPS
    return frames, shown + core.flush()


@pytest.mark.parametrize("rate", [1.0, 2.0, 3.0, 4.0, 6.0])
def test_assumed_delay_credits_the_step_reacted_to(rate):
    """For every true lag (0..2 steps + 0.5) and perception lag in the measured range, the step the observer
    reacted to gets credit under the assumed delay (steps of equal length, unit one step)."""
    probs = face_assumed_delay(rate)
    assert abs(sum(probs) - 1) < 1e-3 and min(probs) >= 0
    model = DelayModel(probs, 1.0)
    times = np.arange(0.0, 40.0)
    k = 20
    for d in (0, 1, 2):
        for lag in np.linspace(*PERCEPTION_LAG_S, 7):
            t_f = k + d + 0.5 + lag * rate
            w, _ = credit_weights(t_f, times, model)
            assert w[k] > 0, (rate, d, lag, probs)


def test_assumed_delay_at_the_default_pace_is_the_papers_shifted_by_one_step():
    assert face_assumed_delay(3.0) == (0.0, 0.3333, 0.3333, 0.3334)
    assert face_assumed_delay(1.0) == (0.3333, 0.3333, 0.3334)


def test_reactions_become_clips_one_at_a_time():
    cfg = FaceVideoConfig(p_feedback=1.0, delay_probs=(1.0,), step_unit=0.5, clip_s=0.5, gap_s=0.6)
    core = FaceVideoCore(cfg, tiny_library())
    n_clip = int(round(0.5 * FPS))
    # a step every 0.5 s, alternating good and bad: each gets a reaction due 0.25 s after it
    steps = [step(i, 100.0 + 0.5 * i, good=i % 2 == 0) for i in range(12)]
    frames, shown = play(core, steps, until=107.0)
    assert shown, "no reaction was shown"
    busy_until = -1.0
    for s in shown:
        assert s.t_start >= s.t_due and s.t_start - s.t_due < 1.0 / FPS + 1e-9  # first frame at or after due
        assert s.t_start >= busy_until - 1e-9  # never before the previous clip + gap is over
        busy_until = s.t_end + 1.0 / FPS + cfg.gap_s
        assert s.last_frame - s.first_frame + 1 == n_clip
        seg = range(30, 60) if s.value == 1 else range(0, 30)
        assert s.first_frame in seg and s.last_frame in seg
        assert s.value == s.intended == (1 if s.ref_seq % 2 == 0 else -1)
        shown_frames = [idx for t, idx in frames if s.t_start - 1e-9 <= t <= s.t_end + 1e-9]
        assert shown_frames == list(range(s.first_frame, s.last_frame + 1))
    c = core.counters
    assert c["reactions"] == 12 and c["reactions_shown"] == len(shown) and c["reactions_skipped_busy"] > 0
    assert c["reactions_shown"] + c["reactions_skipped_busy"] + len(core._pending) == c["reactions"]
    assert sum(idx is None for _, idx in frames) == c["idle_frames"]


def test_end_drops_pending_reactions_and_waits_for_the_gap():
    cfg = FaceVideoConfig(p_feedback=1.0, delay_probs=(0.0, 0.0, 1.0), step_unit=1.0, clip_s=0.5, gap_s=0.6)
    core = FaceVideoCore(cfg, tiny_library())
    for i in range(3):
        core.on_step(step(i, 100.0 + i, good=True))
    core.drop_pending()
    assert core.counters["reactions_dropped_at_end"] == 3
    assert core.idle_after(100.0)


def test_flipped_reactions_show_the_opposite_expression():
    cfg = FaceVideoConfig(p_feedback=1.0, delay_probs=(1.0,), step_unit=2.0, clip_s=0.25, gap_s=0.1, flip=1.0)
    core = FaceVideoCore(cfg, tiny_library())
    _, shown = play(core, [step(i, 100.0 + 2 * i, good=True) for i in range(3)], until=106.0)
    assert shown and all(s.value == -1 and s.intended == 1 for s in shown)


def reaction(seq, t0, value=1, intended=None, dur=0.75):
    return ObserverReaction(
        run="r",
        teacher_id="face",
        seq=seq,
        ref_seq=seq,
        lag_steps=0,
        value=value,
        intended=value if intended is None else intended,
        t_start=t0,
        t_end=t0 + dur,
        camera="face",
        clip="pexels:0-17",
    )


def fb(seq, t, value):
    return Feedback(run="r", teacher_id="face", seq=seq, t_reaction=t, value=value, source="face")


def test_face_metrics_matches_feedback_to_reactions_by_capture_time():
    rs = [reaction(0, 10.0, 1), reaction(1, 12.0, -1), reaction(2, 14.0, 1), reaction(3, 16.0, -1, intended=1)]
    fbs = [
        fb(0, 10.3, 1),  # read
        fb(1, 10.6, 1),  # a second firing in the same clip: extra
        fb(2, 12.4, 1),  # wrong polarity
        fb(3, 13.5, -1),  # while no face was shown: extra
        # reaction 2 missed
        fb(4, 16.3, -1),
    ]  # read as shown, but the observer meant +1 (a simulated misread)
    m = face_metrics(rs, fbs)["face"]
    assert m["reactions_shown"] == 4 and m["reactions_read"] == 3 and m["missed"] == 1 and m["extra"] == 2
    assert m["polarity_errors"] == 2 and m["polarity_error_rate"] == pytest.approx(2 / 3, abs=1e-4)
    assert m["perception_polarity_errors"] == 1 and m["shown_flipped"] == 1
    assert m["lag_s"]["p50"] == pytest.approx(0.3, abs=1e-6) and m["lag_s"]["max"] == pytest.approx(0.4, abs=1e-6)


def test_face_metrics_with_nothing_read():
    m = face_metrics([reaction(0, 1.0)], [])["face"]
    assert m["missed"] == 1 and m["polarity_error_rate"] is None and m["lag_s"] is None


def test_launcher_defaults_for_face_video():
    from services.launcher import UpConfig

    c = UpConfig(teacher="face-video")
    assert c.rate == 3.0 and c.agent.assumed_delay_probs == (0.0, 0.3333, 0.3333, 0.3334) and c.teacher_id == "face"
    c = UpConfig.flat(teacher="face-video", rate=1.0, teacher_id="me", assumed_delay_probs=(0.5, 0.5), end_grace=20)
    assert (c.rate, c.teacher_id, c.agent.assumed_delay_probs, c.end_grace) == (1.0, "me", (0.5, 0.5), 20)
    assert face_video_defaults(UpConfig()) == {
        "rate": 3.0,
        "assumed_delay_probs": (0.0, 0.3333, 0.3333, 0.3334),
        "teacher_id": "face",
        "end_grace": 8.0,
    }
    assert UpConfig().rate == 0.0  # the oracle is untouched


def test_launcher_builds_perception_and_observer_processes(tmp_path):
    from services.launcher import Launch, UpConfig, build_processes

    launch = Launch(UpConfig(teacher="face-video", out=str(tmp_path)), "r1", tmp_path, "tcp/127.0.0.1:7447")
    procs, teachers = build_processes(launch)
    names = [p.name for p in procs]
    assert teachers == ["teacher.face"]
    assert names.index("teacher.face") < names.index("observer.face") < names.index("actor")
    by = {p.name: p for p in procs}
    assert by["teacher.face"].module == "services.perception"
    assert by["teacher.face"].config.source == "zenoh:face"
    assert by["teacher.face"].config.stop_with == ("observer.face",)
    assert by["observer.face"].config.step_unit == pytest.approx(1 / 3)
    assert set(by["actor"].config.wait_for) >= {"teacher.face", "observer.face", "learner", "recorder"}
    assert by["learner"].config.wait_teachers == ("face",)
    assert by["actor"].config.rate == 3.0


def test_observer_reaction_message():
    r = reaction(3, 5.0)
    assert decode(reaction_key("r", "face"), r.encode()) == r
    with pytest.raises(ProtocolError) as e:
        decode(reaction_key("r", "other"), r.encode())
    assert e.value.reason == "bad_value"
    with pytest.raises(ProtocolError) as e:
        dataclasses.replace(r, t_end=4.0).encode()
    assert e.value.reason == "bad_value"


def test_config_is_validated():
    for bad in (dict(clip_s=0), dict(gap_s=-1), dict(width=8), dict(p_feedback=2), dict(camera="a/b")):
        with pytest.raises(ValueError):
            FaceVideoConfig(**bad)


def test_mcap_source_reads_a_sessions_camera_frames(tmp_path, onnx_path, capsys):
    """`mcap:LOG` yields the recorded frames with their capture times; a record that is not an image, or whose
    bytes are not a JPEG, is reported (not a crash); `classify mcap:LOG` prints one line per good frame."""
    import cv2

    from common.logs.mcap_log import LogWriter
    from common.perception import assets
    from common.perception.media import load_video
    from common.protocol import CompressedImage, RunConfig, Time, camera_key
    from services.perception.__main__ import cli
    from services.perception.sources import iter_mcap, iter_mcap_frames

    frames, _ = load_video(assets.media_path("single_face_video"))
    log = tmp_path / "session.mcap"
    t0 = 1_700_000_000.0
    with LogWriter(log, RunConfig.create("r", {})) as w:
        for i in range(6):
            data = cv2.imencode(".jpg", frames[i])[1].tobytes() if i != 3 else b"not a jpeg"
            w.write(
                camera_key("r", "cam"),
                CompressedImage(timestamp=Time.from_seconds(t0 + i / 30), frame_id="cam", data=data, format="jpeg"),
            )
        w.write(camera_key("r", "cam"), b"{broken")
        w.write(
            camera_key("r", "other"),
            CompressedImage(timestamp=Time.from_seconds(t0), frame_id="other", data=b"x", format="jpeg"),
        )
    got = list(iter_mcap_frames(str(log), camera="cam"))
    assert [f.index for f in got] == list(range(7))
    assert got[0].t_capture == pytest.approx(t0) and got[5].t_capture == pytest.approx(t0 + 5 / 30)
    assert got[6].data is None and got[6].error == "malformed"
    bad = []
    good = list(iter_mcap(str(log), on_bad=bad.append))
    assert [f.index for f in good] == [0, 1, 2, 4, 5] and len(bad) == 3  # bad JPEG, broken record, "x"
    assert cli(["classify", f"mcap:{log}"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 5 and all("box=[" in line for line in lines)
    empty = tmp_path / "empty.mcap"
    with LogWriter(empty, RunConfig.create("r", {})):
        pass
    assert cli(["classify", f"mcap:{empty}"]) == 2
    assert "no camera frames" in capsys.readouterr().err


def test_face_video_without_the_wheels_names_make_setup(tmp_path, monkeypatch):
    from services.launcher import UpConfig
    from services.teacher.face_video import cli as observer_cli

    monkeypatch.setenv("HITL_CACHE", str(tmp_path))
    with pytest.raises(ValueError, match="make setup"):
        UpConfig(teacher="face-video")
    assert observer_cli(["--run", "x"]) == 2
