"""The console page in a real headless Chromium, against a real live run (`services up --teacher web`):
the run waits for its first page, the page draws the maze, key presses become feedback credited to the steps
shown 0.2-4 s before each press, pause stops the actor, and the run's log holds every press with its page time and
its system time."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from common.envs.maze import SIZE, make_layout
from common.logs.mcap_read import read_log
from common.protocol import Credit, Feedback, Shown, Step

from .harness import WebRun, browser, canvas_pixels, open_console, uniform_weights

pytestmark = [pytest.mark.live, pytest.mark.browser]

LAYOUT = 3
WALL_BGR = np.array([0x33, 0x33, 0x33])


def test_page_draws_the_maze_credits_presses_pauses_and_logs(tmp_path):
    from playwright.sync_api import sync_playwright

    run = WebRun(
        tmp_path,
        "page",
        "--env",
        "maze",
        "--layout",
        str(LAYOUT),
        "--algo",
        "dqn-tamer",
        "--episodes",
        "200",
        "--rate",
        "4",
        "--seed",
        "1",
        "--start-paused",
        "true",
        # the exact weights below are Deep TAMER's fixed rule (the default learns each person's delay)
        "--screen-delay",
        "uniform:0.2,4",
        "--screen-credit",
        "interval",
    )
    try:
        url = run.url()
        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / "profile")
            page = open_console(ctx, url)

            assert "the run starts when the first page opens" in run.out

            # 1. The maze as drawn: each cell's colour (away from the agent and goal marks) against the layout.
            pixels = canvas_pixels(page)
            assert pixels.shape[:2] == (480, 480)
            cell = 480 // SIZE
            walls = make_layout(LAYOUT).walls
            for r in range(SIZE):
                for c in range(SIZE):
                    bgr = pixels[r * cell + 6, c * cell + 6].astype(int)
                    is_wall = np.abs(bgr - WALL_BGR).max() <= 12
                    assert is_wall == walls[r][c], f"cell {r},{c}: pixel {bgr}, layout wall {walls[r][c]}"

            # 2. Key presses, as a person would: + - ArrowUp ArrowDown, about a second apart, once 4 s were shown.
            page.wait_for_function("hitl.shownLog.length >= 18", timeout=30_000)
            keys = ["+", "-", "ArrowUp", "ArrowDown", "+", "ArrowDown"]
            for key in keys:
                page.keyboard.press(key)
                time.sleep(0.9)
            page.wait_for_function(
                f"[...hitl.mine.values()].filter(f => f.credit).length >= {len(keys)}", timeout=30_000
            )
            presses = page.evaluate("hitl.pressLog")
            mine = page.evaluate("[...hitl.mine.values()]")
            shown = page.evaluate("hitl.shownLog")
            assert [p["value"] for p in presses] == [1, -1, 1, -1, 1, -1]
            for s in shown:  # the console never places a paint before the action (its clock check)
                s["t_sys"] = max(s["t_sys"], s["t_action"])
            for fb in mine:
                assert fb["credit"]["status"] == "credited", fb["credit"]
            # The trail lists them newest first, each with the steps it was credited to (drawn with a step's paint).
            page.wait_for_function(
                f"[...document.querySelectorAll('#trail li')].filter(li => li.textContent.includes('steps')).length"
                f" === {len(keys)}",
                timeout=10_000,
            )
            trail = page.evaluate("[...document.querySelectorAll('#trail li')].map(li => li.textContent)")
            assert len(trail) == len(keys)
            for line, fb in zip(trail, reversed(mine)):
                head, listed = line.split(" -> steps ")
                assert head == f"{'+1' if fb['value'] > 0 else '-1'} #{fb['seq']}"
                assert [int(x.split(" ")[0]) for x in listed.split(", ")] == [q["seq"] for q in fb["credit"]["steps"]]

            # 3. A second person is a teacher of their own; what no page should send is counted and dropped.
            other = open_console(ctx, run.another_address())
            assert other.evaluate("hitl.me") == "web-2"
            other.wait_for_function("hitl.shownLog.length >= 6", timeout=30_000)
            other.keyboard.press("+")
            other.wait_for_function(
                "[...hitl.mine.values()].some(f => f.credit && f.credit.status === 'credited')", timeout=30_000
            )
            other.evaluate("""() => {
                hitl.sentBefore = hitl.mine.size;
                const ws = hitl.ws, now = (performance.timeOrigin + performance.now()) / 1000;
                ws.send('{not json');
                ws.send(JSON.stringify({type: 'bogus'}));
                ws.send(JSON.stringify({type: 'feedback', value: 1, t_page: 1.0, offset: 0, rtt: 0}));
                ws.send(JSON.stringify({type: 'feedback', value: 7, t_page: now, offset: hitl.clock.offset, rtt: 0}));
                ws.send(JSON.stringify({type: 'control', command: 'pace', rate: 1e9}));
                ws.send('x'.repeat(5000));
                ws.send(new Uint8Array([1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]));
                for (let i = 0; i < 40; i++)
                    ws.send(JSON.stringify({type: 'feedback', value: -1, t_page: now,
                                            offset: hitl.clock.offset, rtt: 0}));
            }""")
            # each of the 40 presses is answered, sent or refused; how many the bucket refills for while the
            # console reads them depends on the machine's load (at most 16 at once, then 8 a second)
            other.wait_for_function(
                "(hitl.rejected.flood || 0) + hitl.mine.size - hitl.sentBefore >= 40", timeout=30_000
            )
            rejected = other.evaluate("hitl.rejected")
            for reason in (
                "malformed",
                "unknown_kind",
                "absurd_timestamp",
                "bad_value",
                "oversized",
                "bad_frame",
                "flood",
            ):
                assert rejected.get(reason, 0) >= 1, (reason, rejected)
            floods = rejected["flood"]
            # A better clock estimate 2 s behind is slewed in at half speed, so the page's system time never runs
            # backwards (the console drops a paint older than the last); one ahead is taken at once.
            times = other.evaluate("""() => {
                const c = hitl.clock, t0 = pageNow(), out = [];
                c.target = c.offset - 2; c.slewedAt = t0;
                for (let k = 0; k <= 20; k++) { const st = stamp(t0 + 0.5 * k); out.push(st.t_page + st.offset - t0); }
                c.target = c.offset + 1;
                const st = stamp(t0 + 10.5);
                out.push(st.t_page + st.offset - t0);
                return out;
            }""")
            offset0 = times[0]
            assert all(b > a for a, b in zip(times, times[1:])), times
            assert times[8] == pytest.approx(offset0 + 2.0, abs=1e-6)  # 4 s at half speed: 2 s caught up
            assert times[20] == pytest.approx(offset0 + 10 - 2, abs=1e-6)
            assert times[21] == pytest.approx(offset0 + 10.5 - 2 + 1, abs=1e-6)
            other.close()

            # 4. Pause stops the actor; resume starts it again.
            page.click("#pause")
            page.wait_for_function("hitl.paused === true", timeout=10_000)
            time.sleep(0.6)  # a step already in flight may still land
            seq_paused = page.evaluate("hitl.step.seq")
            t_paused = time.time()
            # A press while paused: its answers are drawn although no step is painted.
            page.keyboard.press("+")
            page.wait_for_function(
                """n => {
                    const f = hitl.mine.get(n), li = document.querySelector('#trail li');
                    return !!(f && f.credit && li) && li.textContent === `+1 #${n} -> steps ` +
                        f.credit.steps.map(s => `${s.seq} (${s.weight.toFixed(2)})`).join(', ');
                }""",
                arg=len(keys),
                timeout=10_000,
            )
            time.sleep(2.5)
            assert page.evaluate("hitl.step.seq") == seq_paused
            t_resumed = time.time()
            page.click("#pause")
            page.wait_for_function(f"hitl.step.seq > {seq_paused} + 2", timeout=10_000)

            # 5. End the run from the page.
            page.click("#end")
            assert run.wait(90) == 0, run.out[-3000:]
            assert page.errors == []
            ctx.close()
    finally:
        run.close()

    # 6. The log: every press with its page time and system time; the paints; the credits; no step while paused.
    feedback = {}
    credits, shown_log, steps = [], [], []
    for rec in read_log(run.rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Feedback) and m.teacher_id == "web-1":
            feedback[m.seq] = m
        elif isinstance(m, Credit):
            credits.append(m)
        elif isinstance(m, Shown):
            shown_log.append(m)
        elif isinstance(m, Step):
            steps.append(m)
    # The actor waited for the first page: its very first step was painted on that page.
    assert min(s.seq for s in shown_log if s.screen == "web-1") == 0
    assert sorted(feedback) == list(range(len(presses) + 1))  # and the press while paused
    episode_of = {m.seq: m.episode for m in steps}
    page_time = {s["seq"]: s["t_sys"] for s in shown}
    credit_of = {fb["seq"]: fb["credit"] for fb in mine}
    for press, seq in zip(presses, sorted(feedback)):
        fb = feedback[seq]
        assert fb.source == "key" and fb.value == press["value"]
        assert fb.t_page == pytest.approx(press["t_page"], abs=1e-6)
        assert fb.t_reaction == pytest.approx(press["t_sys"], abs=1e-6)
        assert fb.shown and fb.actor
        # The press lists what the console knew the page had painted (times as the page stamped them; never
        # later: a paint stamped ahead of the console's clock is placed at its arrival), and is credited with
        # Deep TAMER's uniform rule over those intervals. (Against the page's own log the weights differ when
        # a loaded page's clock estimate is corrected by seconds mid-run: CI saw 2 s.)
        for step in fb.shown:
            assert step.seq in page_time and step.t <= page_time[step.seq] + 1e-6, (step, page_time.get(step.seq))
        listed = [{"seq": q.seq, "t_sys": q.t, "episode": episode_of[q.seq]} for q in fb.shown]
        want = uniform_weights(fb.t_reaction, listed)
        credit = credit_of[seq]
        got = {q["seq"]: q["weight"] for q in credit["steps"]}
        assert set(got) == set(want), (got, want, listed)
        for q, w in want.items():
            assert got[q] == pytest.approx(w, abs=1e-6), (q, got, want, listed)
            start = next(x["t_sys"] for x in listed if x["seq"] == q)
            assert start <= fb.t_reaction - 0.2  # shown at least 0.2 s before the press...
            nxt = [x["t_sys"] for x in listed if x["seq"] > q]
            assert not nxt or nxt[0] >= fb.t_reaction - 4.0  # ...and still on screen 4 s before it
        assert sum(got.values()) + credit["lost_mass"] == pytest.approx(1.0, abs=1e-6)
    assert {c.seq for c in credits if c.teacher_id == "web-1"} >= set(feedback)
    assert len([s for s in shown_log if s.screen == "web-1"]) >= 18
    assert {s.screen for s in shown_log} == {"web-1", "web-2"}
    paused = [s.seq for s in steps if t_paused < s.t_action < t_resumed]
    assert paused == [], f"steps taken while paused: {paused}"
    stats = json.loads((run.rundir / "stats" / "teacher.web.json").read_text())["counters"]
    assert stats["page_rejected_malformed"] >= 1 and stats["page_rejected_flood"] == floods
    assert stats["people_joined"] == 2
    delay = json.loads((run.rundir / "summary.json").read_text())["delay"]
    assert delay["web-1"]["feedbacks"] == len(presses) + 1 and delay["web-1"]["median_s"] == pytest.approx(2.1)
