"""No press is ever lost (issue 25), in a real headless Chromium against a real live run: a named person presses,
the console is SIGKILLed in the middle of their presses and restarted by the launcher, the person reloads the page,
then closes it and comes back (`?name=alice` again). Every press becomes one feedback seq of its own, is logged
once as that seq and credited once; summary.json says so per person."""

from __future__ import annotations

import json
import os
import signal
import time
from urllib.parse import urlsplit

import psutil
import pytest

from common.logs.mcap_read import read_log
from common.protocol import Credit, Feedback

from .harness import WebRun, _listening, browser, open_console, with_query

pytestmark = [pytest.mark.live, pytest.mark.browser, pytest.mark.timeout(400)]

ALL_ACKNOWLEDGED = "hitl.held.length === 0"


def service_pid(run: WebRun, module: str = "services.console") -> int:
    for p in psutil.Process(run.popen.pid).children(recursive=True):
        try:
            if module in p.cmdline():
                return p.pid
        except psutil.NoSuchProcess:
            continue
    raise AssertionError(f"no {module} process")


def press(page, keys: list[str], gap_s: float) -> None:
    for key in keys:
        page.keyboard.press(key)
        time.sleep(gap_s)


def test_a_killed_console_and_a_returning_person_lose_no_press(tmp_path):
    from playwright.sync_api import sync_playwright

    run = WebRun(
        tmp_path,
        "noloss",
        "--env",
        "maze",
        "--layout",
        "2",
        "--episodes",
        "400",
        "--max-steps",
        "6000",
        "--rate",
        "8",
        "--seed",
        "7",
    )
    try:
        url = with_query(run.url(), "name=alice")
        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / "profile")
            page = open_console(ctx, url)
            assert page.evaluate("hitl.me") == "web-alice"
            page.wait_for_function("hitl.shownLog.length >= 10", timeout=30_000)

            press(page, ["+", "-", "+", "-"], 0.4)  # 1. acknowledged as usual
            page.wait_for_function(ALL_ACKNOWLEDGED, timeout=30_000)

            # 2. The console publishes 4 presses, and dies before their Credits come back (the learner is held
            # for a moment, so that they cannot come back sooner): the page still holds all 4.
            learner = service_pid(run, "services.learner")
            os.kill(learner, signal.SIGSTOP)
            try:
                press(page, ["+", "+", "-", "-"], 0.1)
                page.wait_for_function("hitl.held.length === 4 && hitl.held.every(h => h.seq !== null)", timeout=10_000)
                killed = service_pid(run)
                os.kill(killed, signal.SIGKILL)
            finally:
                os.kill(learner, signal.SIGCONT)
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:  # the launcher restarts it (same port, same token)
                try:
                    if service_pid(run) != killed:
                        break
                except AssertionError:
                    pass
                time.sleep(0.2)
            assert service_pid(run) != killed, "the launcher did not restart the console"
            while not _listening(urlsplit(url).port) and time.monotonic() < deadline:
                time.sleep(0.2)
            page.reload()  # the person reloads: the presses not yet acknowledged are kept by the tab
            page.wait_for_function("window.hitl && hitl.hello && hitl.clock.ready", timeout=120_000)
            assert page.evaluate("hitl.me") == "web-alice"
            page.wait_for_function(ALL_ACKNOWLEDGED, timeout=60_000)

            page.close()  # 3. the person leaves and comes back with the same name (a new tab)
            again = open_console(ctx, with_query(run.another_address(), "name=alice"))
            assert again.evaluate("hitl.me") == "web-alice"
            again.wait_for_function("hitl.shownLog.length >= 10", timeout=30_000)
            press(again, ["-", "+", "-", "+"], 0.4)
            again.wait_for_function(ALL_ACKNOWLEDGED, timeout=30_000)
            assert again.evaluate("hitl.dropped") == []
            again.click("#end")
            assert run.wait(120) == 0, run.out[-3000:]
            ctx.close()
    finally:
        run.close()

    seqs, credited, duplicates = [], {}, 0
    for rec in read_log(run.rundir / "session.mcap", dedup=False):  # (the reader would hide re-sends)
        m = rec.message
        if isinstance(m, Feedback) and m.teacher_id == "web-alice":
            seqs.append(m.seq)
        elif isinstance(m, Credit) and m.teacher_id == "web-alice":
            if m.status == "duplicate":
                duplicates += 1
            else:
                assert m.seq not in credited, f"seq {m.seq} credited twice"
                credited[m.seq] = m.status
    assert sorted(set(seqs)) == list(range(12)), seqs  # 12 presses, 12 seqs, none reused
    assert sorted(credited) == list(range(12)), credited  # each one resolved once by the learner
    assert set(credited.values()) == {"credited"}, credited
    summary = json.loads((run.rundir / "summary.json").read_text())
    alice = summary["people"]["web-alice"]
    assert alice["received"] == 12 and alice["published"] == 12 and alice["logged"] == 12, alice
    assert alice["credited"] == 12 and alice["dropped"] == {}, alice
    # The 4 held presses came back with their own seqs (a loaded machine may re-send one more after a second
    # reconnect: seen once, 5) and the learner, which had them, acknowledged them without crediting again.
    assert alice["resent"] >= 4 and duplicates >= 4, (alice, duplicates)
