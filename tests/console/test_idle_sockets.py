"""Sockets held for free (issue 33), against a live run in a real headless Chromium: an attacker opens
HITL_IDLE_SOCKETS (default 1,000; 5,000 measured once, docs/notes/2026-11-28-console-door.md) idle connections to
the console and one that sends a header byte a second. The console holds at most its per-address cap of them, closes
the slow one at its header timeout, and counts each; a person's open page and a person arriving during the attack
both teach, and every one of their presses is credited."""

from __future__ import annotations

import json
import os
import socket
import threading
import time

import pytest

from services.console.config import ConsoleConfig

from .harness import WebRun, browser, open_console, port_of

pytestmark = [pytest.mark.live, pytest.mark.browser, pytest.mark.timeout(500)]

IDLE = int(os.environ.get("HITL_IDLE_SOCKETS", "1000"))
CREDITED = "[...hitl.mine.values()].filter(f => f.credit && f.credit.status === 'credited').length"
STATUSES = "[...hitl.mine.values()].map(f => f.credit ? f.credit.status : 'none')"


def hold_idle(port: int, n: int) -> list[socket.socket]:
    """n connections that never send a byte (the console closes most at once: they stay open on this side)."""
    held = []
    for _ in range(n):
        s = socket.socket()
        s.settimeout(10)
        s.connect(("127.0.0.1", port))
        held.append(s)
    return held


def slow_header(port: int, stop: threading.Event, closed: list[float]) -> None:
    """A header byte a second, until the console closes the connection."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        t0 = time.monotonic()
        for byte in b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 60:
            if stop.is_set():
                return
            try:
                s.sendall(bytes([byte]))
            except OSError:
                break
            time.sleep(1.0)
        closed.append(time.monotonic() - t0)


def teach(page, n: int) -> None:
    for k in range(n):
        page.keyboard.press("+" if k % 2 == 0 else "-")
        time.sleep(0.4)


def test_a_person_teaches_through_thousands_of_idle_sockets(tmp_path):
    from playwright.sync_api import sync_playwright

    cap = ConsoleConfig().max_connections_per_address
    run = WebRun(
        tmp_path,
        "idle",
        "--env",
        "maze",
        "--layout",
        "2",
        "--episodes",
        "400",
        "--max-steps",
        "6000",
        "--rate",
        "4",
        "--seed",
        "3",
    )
    held: list[socket.socket] = []
    stop, closed = threading.Event(), list[float]()
    slow = None
    try:
        url = run.url()
        port = port_of(url)
        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / "profile")
            page = open_console(ctx, url)
            page.wait_for_function("hitl.shownLog.length >= 6", timeout=60_000)
            slow = threading.Thread(target=slow_header, args=(port, stop, closed), daemon=True)
            slow.start()
            held = hold_idle(port, IDLE)
            teach(page, 10)  # the person already teaching goes on
            late = open_console(ctx, run.another_address())  # a person arriving during the attack gets in
            late.wait_for_function("hitl.shownLog.length >= 6", timeout=60_000)
            teach(late, 10)
            for p in (page, late):
                try:
                    p.wait_for_function(f"{CREDITED} === 10 && hitl.held.length === 0", timeout=60_000)
                except Exception as e:  # what became of each press says why
                    state = p.evaluate(
                        f"({{statuses: {STATUSES}, held: hitl.held.length, shown: hitl.shownLog.length}})"
                    )
                    raise AssertionError(f"{'late' if p is late else 'first'} page: {state}; {run.out[-2000:]}") from e
                assert p.evaluate("hitl.dropped") == []
            slow.join(30)
            assert closed and closed[0] <= 12.0, closed  # the header timeout (10 s) and one sweep
            page.click("#end")
            assert run.wait(120) == 0, run.out[-3000:]
            ctx.close()
    finally:
        stop.set()
        for s in held:
            s.close()
        run.close()
    stats = json.loads((run.rundir / "stats" / "teacher.web.json").read_text())["counters"]
    assert stats["door_evicted_address_cap"] >= IDLE - cap, stats
    assert stats["door_closed_header_timeout"] >= 1 and stats["connections_most"] <= cap, stats
    assert stats.get("door_refused_address_cap", 0) == 0 and stats.get("page_errors", 0) == 0, stats
