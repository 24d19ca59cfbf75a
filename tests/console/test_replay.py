"""`python -m services.console --replay LOG` in headless Chromium (Debian's, via Playwright): the recorded session
scrubs step by step, the agent is drawn where the log says it was, each feedback lists and tints the steps it was
credited to, and Q and H are there for every step."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from common.logs.mcap_log import read_log
from common.protocol import Credit, Step
from tests.services.live import ROOT, assert_nothing_left, env, kill_tree, start_up

from .harness import _listening, browser

pytestmark = pytest.mark.live
AGENT_BGR = (185, 128, 41)  # the console's agent colour #2980b9


@pytest.fixture(scope="module")
def session_log(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay")
    launch = start_up(
        tmp, "rp", "--env", "maze", "--layout", "1", "--episodes", "3", "--episode-steps", "150", "--seed", "2"
    )  # three episodes (cut at 150 steps: the first ones here run to 1000)
    assert launch.wait(timeout=300) == 0, launch.out
    assert_nothing_left(launch.rundir)
    return launch.rundir / "session.mcap"


@pytest.fixture()
def replay_url(session_log):
    proc = subprocess.Popen(  # (port 0: the console binds one the system picks, and prints it)
        [sys.executable, "-m", "services.console", "--replay", str(session_log), "--port", "0"],
        cwd=ROOT,
        env=env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        seen = ""
        assert proc.stdout is not None  # (stdout=PIPE)
        for line in proc.stdout:  # the address, with its token, is printed once the server listens
            seen += line
            if line.startswith("replay: "):
                break
        url = line.split()[1]
        port = int(url.split(":")[2].split("/")[0])
        assert url.startswith(f"http://127.0.0.1:{port}/#token=") and _listening(port), seen
        yield url
    finally:
        kill_tree(proc.pid)
        proc.wait(10)


def cell_bgr(page, row: int, col: int, size: int = 8) -> np.ndarray:
    import cv2

    png = page.locator("#scene").screenshot()
    img = np.asarray(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR))[1:-1, 1:-1]
    c = img.shape[0] / size
    return img[int((row + 0.5) * c), int((col + 0.5) * c)].astype(int)


def test_replay_scrubs_the_session_with_scene_feedback_and_q_h(session_log, replay_url, tmp_path):
    from playwright.sync_api import sync_playwright

    steps = [r.message for r in read_log(session_log) if isinstance(r.message, Step)]
    credits = [r.message for r in read_log(session_log) if isinstance(r.message, Credit)]
    assert steps and credits
    with sync_playwright() as p:
        ctx = browser(p, tmp_path / "profile")
        page = ctx.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(replay_url)
        page.wait_for_function("window.replay && replay.ready", timeout=120_000)
        data = page.evaluate("({n: replay.data.steps.length, c: replay.data.credits.length})")
        assert data == {"n": len(steps), "c": len(credits)}

        # Scrub with the slider: the status and the agent's cell follow the log.
        for k in (0, len(steps) // 2, len(steps) - 1):
            page.locator("#scrub").fill(str(k))
            s = steps[k]
            assert page.locator("#step").inner_text() == f"step {s.t_in_episode} (seq {s.seq})"
            row, col = int(s.info["row"]), int(s.info["col"])
            assert np.abs(cell_bgr(page, row, col) - AGENT_BGR).max() < 40, (k, row, col)
        page.keyboard.press("ArrowLeft")
        assert page.evaluate("replay.index") == len(steps) - 2

        # A credited feedback: jump to its first credited step; the side panel names it with the weights and the
        # cell the agent acted from is tinted (not the white of a free cell).
        c = next(c for c in credits if c.status == "credited" and c.steps[0].seq > 0)
        first = c.steps[0].seq
        index = next(i for i, s in enumerate(steps) if s.seq == first and s.incarnation == c.actor)
        page.evaluate(f"replay.setIndex({index})")
        near = page.locator("#near").inner_text()
        expected = ", ".join(f"{s.seq} ({s.weight:.2f})" for s in c.steps)
        assert f"#{c.seq} -> steps {expected}" in near
        before = steps[index - 1]
        if before.episode == steps[index].episode and (int(before.info["row"]), int(before.info["col"])) != (
            int(steps[index].info["row"]),
            int(steps[index].info["col"]),
        ):
            bgr = cell_bgr(page, int(before.info["row"]), int(before.info["col"]))
            assert bgr.min() < 235, bgr  # tinted red or green

        # Q and H for every step, as numbers in the table, and they change as the agent learns.
        rows = page.locator("#prefs tbody tr").all_inner_texts()
        assert len(rows) == 4 and all(re.fullmatch(r"\w+\t-?\d+\.\d{3}\t-?\d+\.\d{3}", r) for r in rows), rows
        q = page.evaluate("replay.data.steps.map((s) => s.q && s.q[0])")
        assert all(v is not None for v in q) and len(set(q)) > 10
        page.screenshot(path=str(tmp_path / "replay.png"), full_page=True)
        assert not errors, errors
        ctx.close()


@pytest.mark.parametrize("content", [b"\x00\x00\x00\x1cftypisom" + bytes(200), bytes(range(256)) * 40])
def test_replay_of_a_file_that_is_not_mcap_is_one_line_and_nonzero(tmp_path, content):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    proc = subprocess.run(
        [sys.executable, "-m", "services.console", "--replay", str(bad)],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "not an MCAP file" in proc.stderr
