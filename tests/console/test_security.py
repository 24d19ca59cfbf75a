"""The console with `--security`, in a real headless Chromium against a real secured run (`services up --teacher web
--security FILE`): HTTPS with the router's certificate (signed by the run's CA), a page whose teacher name or password
is wrong gets no connection and is counted, and a person who logs in teaches as `web-<name>` through the secured
router, the learner crediting their presses."""

from __future__ import annotations

import json
import ssl
import urllib.error
import urllib.request

import pytest

from .harness import WebRun, browser

pytestmark = [pytest.mark.live, pytest.mark.browser, pytest.mark.timeout(300)]

RUN = "secweb"


def answer_prompts(page, answers: list[str]) -> None:
    """The page asks for the teacher name, then the password (window.prompt): answer them in order."""
    queue = list(answers)
    page.on("dialog", lambda d: d.accept(queue.pop(0) if queue else ""))


def test_secured_console_needs_the_password_serves_https_and_credits_the_person(tmp_path):
    from playwright.sync_api import sync_playwright

    from common.security import SECURITY_FILE, init, load_security

    init(tmp_path / "sec", ["web", "alice"], run=RUN)
    sec = tmp_path / "sec" / SECURITY_FILE
    security = load_security(str(sec))
    run = WebRun(
        tmp_path,
        RUN,
        "--security",
        str(sec),
        "--env",
        "maze",
        "--layout",
        "2",
        "--episodes",
        "200",
        "--max-steps",
        "4000",
        "--rate",
        "8",
        "--seed",
        "3",
    )
    try:
        url = run.url()
        assert url.startswith("https://127.0.0.1:"), run.out

        # The certificate is the router's, signed by the run's CA; plain HTTP gets nothing; the printed address's
        # key buys a session key (no cookie), and nothing of the run is served without one.
        base, entry = url.split("#token=")
        ca = ssl.create_default_context(cafile=str(security.path(security.ca_cert)))
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(base + "settings", context=ca, timeout=20)
        assert refused.value.code == 403
        enter = urllib.request.Request(base + "enter", method="POST", headers={"Authorization": f"Bearer {entry}"})
        key = json.loads(urllib.request.urlopen(enter, context=ca, timeout=20).read())["key"]
        settings = urllib.request.Request(base + "settings", headers={"Authorization": f"Bearer {key}"})
        assert json.loads(urllib.request.urlopen(settings, context=ca, timeout=20).read()) == {"login": True}
        with pytest.raises((urllib.error.URLError, ConnectionError, OSError)):
            urllib.request.urlopen(base.replace("https://", "http://") + "settings", timeout=20).read()

        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / "profile", ignore_https_errors=True)
            bare = ctx.new_page()  # the address without a key: the page, and nothing of the run
            bare.goto(base)
            bare.wait_for_function("window.hitl && hitl.refused", timeout=30_000)
            assert "no key" in bare.locator("#who").inner_text() and not bare.evaluate("Boolean(hitl.hello)")
            bare.close()
            intruder = ctx.new_page()
            answer_prompts(intruder, ["alice", "not-the-password"])
            intruder.goto(run.another_address())
            intruder.wait_for_function("window.hitl && hitl.closed === true", timeout=60_000)
            assert not intruder.evaluate("Boolean(hitl.hello)")  # refused before any message

            alice = ctx.new_page()
            answer_prompts(alice, ["alice", security.password(security.username("teacher", "alice"))])
            alice.goto(run.another_address())
            alice.wait_for_function("hitl.hello && hitl.clock.ready && hitl.shownLog.length >= 10", timeout=120_000)
            assert alice.evaluate("hitl.me") == "web-alice"
            for key in ["+", "-", "+"]:
                alice.keyboard.press(key)
                alice.wait_for_timeout(600)
            alice.wait_for_function(
                "[...hitl.mine.values()].filter(f => f.credit && f.credit.status === 'credited').length >= 3",
                timeout=60_000,
            )
            alice.click("#end")  # the person ends the run (the confirm dialog is accepted)
            assert run.wait(120) == 0, run.out[-3000:]
            ctx.close()
    finally:
        run.close()
    s = json.loads((run.rundir / "summary.json").read_text())
    assert s["feedback_credited"] >= 3 and s["unauthenticated_inputs"] == {} and s["rejected_inputs"] == {}
    # no delay option: the person's delay was learned, and summary.json says where it stands
    (person,) = s["delay"].values()
    assert person["feedbacks"] >= 3 and 0 < person["p10_s"] <= person["median_s"] <= person["p90_s"] < 6
    console = s["services"]["teacher.web"]["counters"]
    assert console["login_refused"] >= 1 and console["people_joined"] == 1, console
    assert console["door_refused_no_token"] >= 1, console
    assert s["services"]["teacher.web-alice"]["counters"]["feedback_published"] >= 3
