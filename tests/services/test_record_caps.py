"""The recorder's caps per sender and per second (a flood of big frames cannot fill the disk)."""

from __future__ import annotations

from services.recorder.caps import RecordCaps

MIB = 1 << 20


def test_disk_recorder_caps_camera_frames_and_bytes_per_sender():
    caps = RecordCaps(sender_bytes=32 * MIB, camera_bytes=4 * MIB, camera_fps=30)
    cam = "hitl/r/camera/alice"
    # 40 frames of 8 MB (issue 10's flood) in one second: none fits a camera's 4 MiB/s
    assert not any(caps.admit(cam, 8 * MIB, now=100.0 + i / 40) for i in range(40))
    # real frames (30 KB at 25 fps) all pass, second after second
    assert all(caps.admit(cam, 30_000, now=200.0 + i / 25) for i in range(250))
    # frames per second: at most 30 per camera in a burst; another camera has its own budget
    burst = [caps.admit(cam, 1000, now=400.0) for _ in range(100)]
    assert sum(burst) == 30
    assert caps.admit("hitl/r/camera/bob", 1000, now=400.0)
    # one sender's bytes: a learner's burst beyond 32 MiB in a second is capped, the actor is not affected
    sent = sum(caps.admit("hitl/r/ingest", 512 * 1024, now=500.0) for _ in range(100))
    assert sent == 64
    assert caps.admit("hitl/r/step", 400, now=500.0)
    assert caps.admit("hitl/r/ingest", 512 * 1024, now=501.0)  # refilled a second later
