"""The person's delay estimate on the console page, in a real headless Chromium against a live run: every Credit of
a press carries the learner's current estimate of that person's delay (`Credit.delay`), and the page draws it
(a density over 0-6 s with its median marked in red) with the numbers beside it. The run's recorded log then
tells credit settings apart (`replay LOG retrain --screen-delay ...`): the person's own delay predicts their later
presses better than a wrong one."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys

import numpy as np
import pytest

from common.logs.mcap_read import read_log
from common.protocol import Credit
from services.console.lags import lag_plan

from tests.services.live import ROOT, env

from .harness import SCRIPTED, WebRun, browser, open_console, with_query

pytestmark = [pytest.mark.live, pytest.mark.browser]

LAG = "uniform:0.4,1.2"  # the person's delay (s), which the learner is not told
RED_BGR = np.array([0x2B, 0x39, 0xC0])  # #c0392b, the median line


def delay_pixels(page) -> np.ndarray:
    import cv2

    png = page.locator("#delay").screenshot()
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "the screenshot is not an image"
    return img[1:-1, 1:-1]  # (its 1 px border)


def end_from_the_page(page, run: WebRun, ctx) -> None:
    """The person ends the run from the page; the page saw no error, the run ends cleanly."""
    assert page.errors == []
    page.click("#end")
    assert run.wait(120) == 0, run.out[-3000:]
    ctx.close()


@contextlib.contextmanager
def alice_on_a_page(tmp_path, name: str, layout: int, seed: int):
    """A paced run (4 steps/s, episodes cut at 60 steps) whose people's profiles live in tmp_path/profiles, and
    Alice's page on it: yields (run, browser context, page); the run is stopped however the block ends."""
    from playwright.sync_api import sync_playwright

    common = "--env maze --algo dqn-tamer --episodes 200 --episode-steps 60 --rate 4 --start-paused true".split()
    where = ["--layout", str(layout), "--seed", str(seed), "--profiles", str(tmp_path / "profiles")]
    run = WebRun(tmp_path, name, *common, *where)
    try:
        url = run.url()
        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / f"profile-{name}")
            yield run, ctx, open_console(ctx, with_query(url, "name=alice"))
    finally:
        run.close()


def alice_teaches(tmp_path) -> dict:
    """A named person teaches; the page draws her delay estimate; her profile is written. Returns the profile."""
    profiles = tmp_path / "profiles"
    with alice_on_a_page(tmp_path, "delay", layout=2, seed=3) as (run, ctx, page):
        assert page.evaluate("hitl.me") == "web-alice"
        assert page.locator("#delaytext").inner_text() == "after your first press"
        page.add_script_tag(path=str(SCRIPTED))
        # the person's lags: a plan drawn from a shape in seconds (services/console/lags.py), as the designs do
        plan = lag_plan(LAG, 200, 60, seed=5)
        page.evaluate("o => { hitlScriptedPerson(o); }", {"p": 0.6, "seed": 6, "lags": plan.round(3).tolist()})
        page.wait_for_function("[...hitl.mine.values()].filter(f => f.credit).length >= 40", timeout=150_000)
        page.evaluate("hitl.onShown = []")  # the person stops; their last presses (<= 1.2 s) are credited
        page.wait_for_timeout(2500)
        shown = page.evaluate("hitl.delay")
        credits = page.evaluate("[...hitl.mine.values()].filter(f => f.credit).map(f => f.credit)")
        text = page.locator("#delaytext").inner_text()
        planned = page.evaluate("hitlScriptedPlan")
        pixels = delay_pixels(page)
        width = page.evaluate("document.getElementById('delay').width")
        end_from_the_page(page, run, ctx)

    # Each press came at the lag the plan gave its step.
    assert len(planned) >= 40
    assert all(p["lag"] == pytest.approx(plan[p["episode"], p["t"]], abs=6e-4) for p in planned)
    # Every credit the page got carries an estimate; the one drawn is the newest.
    assert all(c["delay"] is not None for c in credits)
    newest = max(credits, key=lambda c: c["t_credited"])["delay"]
    assert shown == newest
    assert len(shown["probs"]) * shown["bin_s"] == pytest.approx(6.0)
    assert sum(shown["probs"]) == pytest.approx(1.0, abs=1e-3)
    assert 0 < shown["p10_s"] <= shown["median_s"] <= shown["p90_s"] < 6
    assert shown["feedbacks"] >= len(credits) - 1  # (the newest credit's press is counted too)
    assert text.startswith(f"median {shown['median_s']:.2f} s") and f"from {shown['feedbacks']} presses" in text
    # The median line, where the median is: red pixels in the column at median / 6 s of the canvas's width.
    red = np.abs(pixels.astype(int) - RED_BGR).max(axis=2) <= 40
    columns = np.flatnonzero(red.sum(axis=0) >= pixels.shape[0] // 2)
    assert columns.size, "no median line drawn"
    assert abs(columns.mean() - shown["median_s"] / 6.0 * width) <= 3
    # ... and the density: blue pixels (the curve) in most of the columns between p10 and p90, less those the median
    # line covers (a narrow estimate spans 30 columns, 3 of them under the line: a run failed at exactly 0.9).
    blue = np.abs(pixels.astype(int) - np.array([0xB9, 0x80, 0x29])).max(axis=2) <= 40
    lo, hi = int(shown["p10_s"] / 6 * width) + 2, int(shown["p90_s"] / 6 * width) - 2
    under_line = set(np.flatnonzero(red.any(axis=0)).tolist())
    span = [c for c in range(lo, hi) if c not in under_line]
    assert span and blue[:, span].any(axis=0).mean() > 0.9

    # The log holds the same estimates: each Credit of the person's presses, with its delay.
    logged = [
        m.message
        for m in read_log(run.rundir / "session.mcap")
        if isinstance(m.message, Credit) and m.message.teacher_id == "web-alice"
    ]
    delays = [c.delay for c in logged if c.delay is not None]
    assert len(logged) >= len(credits) and len(delays) == len(logged)
    assert max(d.feedbacks for d in delays) >= len(credits)

    # Which delay fits this person, from the recorded log: their own (0.4-1.2 s) against a wrong one (2.5-5.5 s).
    scored = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.replay",
            str(run.rundir),
            "retrain",
            "--screen-delay",
            LAG,
            "--screen-delay",
            "uniform:2.5,5.5",
            "--screen-credit",
            "onset",
            "--fit-share",
            "0.3",
            "--json",
        ],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert scored.returncode == 0, scored.stderr[-2000:]
    rows = {r["delay"]: r for r in json.loads(scored.stdout)}
    assert rows[LAG]["scored"] >= 28 and rows[LAG]["fitted"] >= 12
    assert rows[LAG]["mean_loglik"] > rows["uniform:2.5,5.5"]["mean_loglik"]

    # Alice's estimate outlives the run: her profile holds the last one the learner sent.
    stored = json.loads((profiles / "web-alice.json").read_text())
    last = max(logged, key=lambda c: c.t_credited).delay
    assert last is not None
    assert stored["feedbacks"] == last.feedbacks and np.allclose(stored["probs"], last.probs, atol=1e-4)
    assert not any(d.returning for d in delays)
    return stored


def test_the_page_draws_the_delay_estimate_and_a_returning_person_starts_from_it(tmp_path):
    stored = alice_teaches(tmp_path)
    with alice_on_a_page(tmp_path, "again", layout=4, seed=4) as (run, ctx, page):
        page.wait_for_function("hitl.shownLog.length >= 6", timeout=30_000)
        page.keyboard.press("+")
        page.wait_for_function("hitl.delay", timeout=30_000)
        first = page.evaluate("hitl.delay")
        text = page.locator("#delaytext").inner_text()
        end_from_the_page(page, run, ctx)
    assert first["returning"] and "welcome back" in text
    assert first["feedbacks"] == stored["feedbacks"] + 1  # her earlier presses, and this one
