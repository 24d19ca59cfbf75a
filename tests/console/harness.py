"""Helpers of the console tests: a live run with `--teacher web` as a process, and Debian's Chromium driven by
Playwright (never a downloaded browser build; a browser that cannot start fails the test)."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from services.console.scripted import y4m_from_video  # noqa: F401  (the tests' fake camera too)
from tests.services.live import ROOT, env, kill_tree

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCRIPTED = ROOT / "services" / "console" / "static" / "scripted_person.js"
ADDRESS = r"console: (https?://127\.0\.0\.1:(\d+)/#token=[A-Za-z0-9_.-]+)"  # a one-use address (door.py)


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


class WebRun:
    """`python -m services up --teacher web ...` in its own session; its output collected by a thread."""

    def __init__(self, tmp_path: Path, run: str, *args: str):
        cmd = [
            sys.executable,
            "-m",
            "services",
            "up",
            "--teacher",
            "web",
            "--out",
            str(tmp_path),
            "--run",
            run,
            "--progress",
            "false",
            *([] if "--curve" in args else ["--curve", "false"]),  # (no test of the page reads the curve)
            *args,
        ]
        self.rundir = tmp_path / run
        self.popen = subprocess.Popen(
            cmd,
            cwd=ROOT,
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.popen.stdout is not None  # (stdout=PIPE)
        for line in self.popen.stdout:
            self.lines.append(line)

    @property
    def out(self) -> str:
        return "".join(self.lines)

    def url(self, timeout: float = 150.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = re.search(ADDRESS, self.out)
            if m:  # printed once the console listens
                assert _listening(int(m.group(2))), self.out
                return m.group(1)
            if self.popen.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"no console line from services up:\n{self.out[-3000:]}")

    def another_address(self) -> str:
        """A fresh one-use address, as an open page's 'another page' gives: each printed address opens one page."""
        from services.console.door import Keys, read_or_make_token

        first = self.url()
        secret = read_or_make_token(str(self.rundir / "state" / "teacher.web.token"))
        return first.split("#", 1)[0] + "#token=" + Keys(secret).entry()

    def wait(self, timeout: float) -> int:
        try:
            rc = self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            kill_tree(self.popen.pid)
            raise AssertionError(f"services up still running after {timeout} s:\n{self.out[-3000:]}") from None
        self._reader.join(5)
        return rc

    def close(self) -> None:
        if self.popen.poll() is None:
            kill_tree(self.popen.pid)
            self.popen.wait(10)


def browser(
    playwright,
    user_data_dir: Path,
    extra_args: tuple[str, ...] = (),
    permissions: tuple[str, ...] = (),
    ignore_https_errors: bool = False,
):
    """A headless Chromium context (fresh profile). Raises (the test fails) if the browser cannot start."""
    assert Path(CHROMIUM).exists(), f"{CHROMIUM} is missing: `make setup` installs Debian's chromium"
    return playwright.chromium.launch_persistent_context(
        str(user_data_dir),
        executable_path=CHROMIUM,
        headless=True,
        args=[*FLAGS, *extra_args],
        permissions=list(permissions),
        viewport={"width": 1280, "height": 760},
        ignore_https_errors=ignore_https_errors,
    )


def port_of(address: str) -> int:
    port = urlsplit(address).port
    assert port is not None, address
    return port


def with_query(address: str, query: str) -> str:
    """The address with `query` (e.g. name=alice) before its fragment."""
    base, _, fragment = address.partition("#")
    return f"{base}{'&' if '?' in base else '?'}{query}#{fragment}"


def open_console(ctx, url: str, timeout_ms: int = 120_000):
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("dialog", lambda d: d.accept())
    page.goto(url)
    page.wait_for_function("window.hitl && hitl.hello && hitl.step && hitl.clock.ready", timeout=timeout_ms)
    page.errors = errors
    return page


def scripted_person(run: WebRun, profile: Path, options: str, timeout: float = 180) -> tuple[list, list]:
    """A scripted person (`static/scripted_person.js`, with these JS options) on `run`'s console page until the run
    ends (asserted: exit 0, no page error); returns the person's plan and the page's press log."""
    from playwright.sync_api import sync_playwright

    try:
        url = run.url()
        with sync_playwright() as pw:
            ctx = browser(pw, profile)
            page = open_console(ctx, url)
            page.add_script_tag(path=str(SCRIPTED))
            page.evaluate(f"hitlScriptedPerson({options})")
            assert run.wait(timeout) == 0, run.out[-3000:]
            plan, presses = page.evaluate("hitlScriptedPlan"), page.evaluate("hitl.pressLog")
            assert page.errors == []
            ctx.close()
    finally:
        run.close()
    return plan, presses


def canvas_pixels(page) -> np.ndarray:
    """The scene canvas as it is on screen: BGR pixels of a screenshot of the element."""
    import cv2

    png = page.locator("#scene").screenshot()
    img = np.asarray(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR))
    border = page.evaluate("parseFloat(getComputedStyle(document.getElementById('scene')).borderLeftWidth)")
    b = int(round(border))
    return img[b : img.shape[0] - b, b : img.shape[1] - b]


def uniform_weights(t_feedback: float, shown: list[dict], low: float = 0.2, high: float = 4.0) -> dict[int, float]:
    """What Deep TAMER's uniform delay gives each painted step (independent of the project's credit code):
    the share of [t - high, t - low] that falls in the step's on-screen interval, within the episode of the step
    on screen at t."""
    on = [s for s in shown if s["t_sys"] <= t_feedback]
    if not on:
        return {}
    episode = on[-1]["episode"]
    out = {}
    for k, s in enumerate(on):
        end = on[k + 1]["t_sys"] if k + 1 < len(on) else np.inf
        a, b = max(s["t_sys"], t_feedback - high), min(end, t_feedback - low)
        if b > a and s["episode"] == episode:
            out[s["seq"]] = (b - a) / (high - low)
    return out
