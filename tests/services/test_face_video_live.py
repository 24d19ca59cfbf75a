"""The face-video teacher and the perception service live: real face clips through the real detector and
classifier, over Zenoh on a loopback router (free port, no multicast), each service its own process.

The run (about 100 s): `python -m services up --teacher face-video` on maze layout 6 with seed 4 for 240 steps
at the face-video pace (3 steps/s). Why that layout and seed: a face gives at most about one reaction per 1.4 s
(clip + gap), so feedback is sparse (about 0.15-0.2 per step) and DQN-TAMER's first episodes on the paper's maze
can take hundreds of steps; on layout 2 with seed 4 a virtual-clock replica of this path (the perception
outcome of every clip start, measured, replayed with timing noise) learned within 240 steps in 9 runs of 10.
The maze layouts were regenerated (honest/misleading pools, seeds from (layout, seed)); layout 6 with seed 4 was
then picked by an in-process scan of honest layouts 0-18 x seeds 0-4 at the face path's feedback rate (0.17 per
step, lag 1-3 steps): it finished all 12 episodes within 240 steps there. Live it finishes fewer
(1 to 4 in honest runs), so the test asks for a finished episode that was short (return above 0.5: at most 50 steps).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from common.logs.mcap_log import load_log
from common.protocol import Feedback

from .live import ROOT, assert_nothing_left, env, start_up

pytestmark = pytest.mark.live

STEPS = 240


@pytest.fixture(scope="module")
def face_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("face")
    launch = start_up(
        out,
        "face",
        "--teacher",
        "face-video",
        "--env",
        "maze",
        "--algo",
        "dqn-tamer",
        "--layout",
        "6",
        "--seed",
        "4",
        "--max-steps",
        str(STEPS),
        "--episodes",
        "1000",
    )
    rc = launch.wait(timeout=400)
    assert rc == 0, launch.out
    yield launch
    assert_nothing_left(launch.rundir)


def test_face_video_run_learns_and_reports_the_polarity_error_rate(face_run):
    s = face_run.summary()
    assert s["outcome"] == "ok" and set(s["exit_codes"].values()) == {0}, s["exit_codes"]
    assert s["steps_sent"] == STEPS and s["steps_learned"] == STEPS
    face = s["face"]["face"]
    print(json.dumps(face), s["returns"])
    # about one reaction per 1.4 s can be shown: ~55 in 80 s; every one is accounted for
    assert face["reactions_shown"] >= 25
    assert face["reactions_read"] + face["missed"] == face["reactions_shown"]
    assert face["polarity_error_rate"] is not None and face["polarity_error_rate"] < 0.30
    assert face["miss_rate"] < 0.5 and face["extra"] <= 0.2 * face["reactions_shown"]
    assert 0.2 <= face["lag_s"]["p50"] <= 0.8  # the reaction detector's smoothing lag (about 0.3 s)
    # what the learner got is what perception published, credited to steps
    published = s["services"]["teacher.face"]["counters"]["feedback_published"]
    assert s["feedback_logged"] == published == face["feedback_perceived"]
    assert s["feedback_credited"] >= 0.8 * published
    # It gets somewhere: a finished episode that was short (the goal gives +1, a step -0.01: above 0.5 is at most 50
    # steps). Not a learning curve: with one reaction per 1.4 s over 240 steps, honest runs finished [0.65, 0.92,
    # -0.88], [0.96, 0.71, 0.91], [0.8, -0.97], [0.96, 0.7, 0.92, 0.22, ...] and (a loaded run) only [0.8]; learning
    # from feedback is asserted in process (tests/core) and by the main live run.
    returns = s["returns"]
    finished = [e["return"] for e in s["episodes"] if e["finished"]]
    assert finished and max(finished) > 0.5, returns


def test_face_video_log_holds_frames_predictions_and_reactions_with_schemas(face_run):
    from mcap.reader import make_reader

    with open(face_run.rundir / "session.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    schema_of = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert schema_of["/camera/face"] == "foxglove.CompressedImage"  # Foxglove shows it as an image
    assert schema_of["/perception/face"] == "hitl.ExpressionPrediction"
    assert schema_of["/reaction/face"] == "hitl.ObserverReaction"
    assert schema_of["/feedback/face"] == "hitl.Feedback"
    counts = {ch.topic: summary.statistics.channel_message_counts[cid] for cid, ch in summary.channels.items()}
    s = face_run.summary()
    frames = s["services"]["observer.face"]["counters"]["frames_published"]
    assert counts["/camera/face"] >= 0.95 * frames
    assert counts["/perception/face"] >= 0.95 * frames


def _collect(session, key_expr: str, sink: list):
    return session.declare_subscriber(key_expr, lambda sample: sink.append(sample.payload.to_bytes()))


def test_mcap_source_reruns_perception_on_a_recorded_session(face_run, tmp_path):
    """`--source mcap:LOG` replays the recorded camera frames through perception: same frames, same capture
    times, so the same feedback as the live run (the pipeline is deterministic)."""
    from common.wire.auth import make_run_credentials
    from common.protocol import decode, feedback_key
    from common.wire.transport import free_port, open_session, router_config, tcp_endpoint

    log = face_run.rundir / "session.mcap"
    records, _ = load_log(log)
    live = [
        (r.message.value, r.message.t_reaction)
        for r in records
        if isinstance(r.message, Feedback) and r.key == feedback_key("face", "face")
    ]
    endpoint = tcp_endpoint(free_port())
    got: list[bytes] = []
    with open_session(router_config(endpoint)) as session:
        token = session.liveliness().declare_token("hitl/rerun/alive/tester")
        sub = _collect(session, "hitl/rerun/feedback/face", got)
        creds = make_run_credentials(tmp_path / "creds", "rerun", services=("teacher.face",))
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "services.perception",
                "--source",
                f"mcap:{log}",
                "--connect",
                endpoint,
                "--run",
                "rerun",
                "--wait-for",
                "tester",
                "--realtime",
                "false",
                "--credentials",
                str(creds["teacher.face"]),
                "--publish-frames",
                "false",
                "--stats-out",
                str(tmp_path / "stats.json"),
                "--parent-pid",
                str(os.getpid()),
            ],
            cwd=ROOT,
            env=env(),
            capture_output=True,
            text=True,
            timeout=180,
        )
        time.sleep(0.5)
        sub.undeclare()
        token.undeclare()
    assert out.returncode == 0, out.stdout + out.stderr
    rerun = [decode("hitl/rerun/feedback/face", b) for b in got]
    assert [f.seq for f in rerun] == list(range(len(rerun)))
    rerun_pairs = [(f.value, f.t_reaction) for f in rerun]
    counters = json.loads((tmp_path / "stats.json").read_text())["counters"]
    s = face_run.summary()
    recorded = s["log"]["by_kind"]["camera"]
    assert counters["frames_processed"] == recorded
    if s["services"]["teacher.face"]["counters"]["frames_processed"] == recorded:
        assert rerun_pairs == live  # perception saw exactly the recorded frames live
    else:  # a frame dropped on the live path (congestion DROP) may change a reading or two
        assert len(set(rerun_pairs) & set(live)) >= 0.9 * len(live)


def test_malformed_frames_are_counted_and_dropped(tmp_path):
    """Bad JPEG bytes in a valid CompressedImage, and a payload that is not a CompressedImage at all: both
    counted and skipped; the next good frame is processed; the service exits cleanly."""
    import zenoh

    from common.wire.auth import Auth, load_credential, make_run_credentials
    from common.perception import assets
    from common.perception.media import load_video
    from common.protocol import CompressedImage, Time, camera_key
    from common.wire.transport import free_port, open_session, router_config, tcp_endpoint
    from services.common.runtime import wait_alive
    from services.perception.live import encode_jpeg

    frames, _ = load_video(assets.media_path("single_face_video"))
    endpoint = tcp_endpoint(free_port())
    stats = tmp_path / "stats.json"
    creds = make_run_credentials(tmp_path / "creds", "bad", services=("teacher.face", "observer.cam"))
    camera = Auth(load_credential(creds["observer.cam"]))  # the frames are signed: only their content is bad
    with open_session(router_config(endpoint)) as session:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.perception",
                "--source",
                "zenoh:cam",
                "--connect",
                endpoint,
                "--run",
                "bad",
                "--stats-out",
                str(stats),
                "--parent-pid",
                str(os.getpid()),
                "--credentials",
                str(creds["teacher.face"]),
            ],
            cwd=ROOT,
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        try:
            assert not wait_alive(session, "bad", ["teacher.face"], 60), "perception did not come up"
            pub = session.declare_publisher(camera_key("bad", "cam"), congestion_control=zenoh.CongestionControl.BLOCK)
            now = time.time()

            def put(payload: bytes) -> None:
                pub.put(payload, attachment=camera.sign(camera_key("bad", "cam"), payload))
                time.sleep(0.3)  # one at a time: the service's frame queue drops the oldest when full

            put(
                CompressedImage(
                    timestamp=Time.from_seconds(now), frame_id="cam", data=b"not a jpeg", format="jpeg"
                ).encode()
            )
            put(b"\xff\xd8 raw bytes, not JSON")
            for i in range(3):
                put(
                    CompressedImage(
                        timestamp=Time.from_seconds(now + 0.04 * (i + 1)),
                        frame_id="cam",
                        data=encode_jpeg(frames[i], 80),
                        format="jpeg",
                    ).encode()
                )
            pub.undeclare()
            proc.send_signal(signal.SIGTERM)
            out, _ = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, out
    c = json.loads(stats.read_text())["counters"]
    assert c["frames_undecodable"] == 1, c
    assert c["frames_dropped_malformed"] == 1, c
    assert c["frames_processed"] == 3 and c["frames_with_face"] == 3, c
    assert "cannot be decoded" in out
