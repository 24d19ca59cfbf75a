"""The console's edge (issue 25), in a real headless Chromium against a real live run: only its own people reach
it (a page from another port, a `file://` page and a forged Host are refused before anything of the run is
served), one page cannot break it (a non-ASCII name, a number of 400 digits, 20,000 controls, idle sockets
holding every seat), and the printed address still opens the page with one click."""

from __future__ import annotations

import http.client
import http.server
import json
import threading
from functools import partial
from urllib.parse import urlsplit

import pytest

from common.logs.mcap_read import read_log
from common.protocol import Control
from common.wire.transport import free_port

from .harness import WebRun, browser, open_console, port_of, with_query

pytestmark = [pytest.mark.live, pytest.mark.browser, pytest.mark.timeout(400)]

INTRUDER = """<!doctype html><script>
window.result = {ws: "pending", msgs: 0};
const ws = new WebSocket("ws://127.0.0.1:PORT/ws");
ws.onmessage = () => { window.result.msgs++; };
ws.onopen = () => { window.result.ws = "open"; ws.send(JSON.stringify({type: "control", command: "end"})); };
ws.onclose = () => { if (window.result.ws === "pending") window.result.ws = "refused"; };
fetch("http://127.0.0.1:PORT/settings", {credentials: "include"}).then(
  (r) => { window.result.fetch = r.status; }, () => { window.result.fetch = "blocked"; });
</script>"""


class Answer:
    """An HTTP answer, read whole."""

    def __init__(self, resp: http.client.HTTPResponse):
        self.status, self.body, self.headers = resp.status, resp.read(), resp.headers

    def getheader(self, name: str) -> str | None:
        return self.headers.get(name)


def request(port: int, path: str, headers: dict, method: str = "GET") -> Answer:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    conn.request(method, path, headers=headers)
    answer = Answer(conn.getresponse())
    conn.close()
    return answer


def check_raw_http(url: str) -> str:
    """The door by plain HTTP: the printed address's key buys a session key once, and no cookie; returns it."""
    port, entry = port_of(url), urlsplit(url).fragment.split("=", 1)[1]
    own = {"Host": f"127.0.0.1:{port}"}
    for path in ("/settings", "/ws", "/invite"):  # nothing of the run without a key
        r = request(port, path, own)
        assert r.status == 403 and b"Not open to this page" in r.body, (path, r.status)
    r = request(port, "/", own)  # the page itself: shipped files only, no cookie
    assert r.status == 200 and r.getheader("Set-Cookie") is None
    for host in ("evil.example", f"evil.example:{port}", f"127.0.0.1:{port + 1}", "localhost"):  # forged Host
        assert request(port, "/", {"Host": host}).status == 403, host
    enter = {"Authorization": f"Bearer {entry}"}
    r = request(port, "/enter", {**own, **enter, "Origin": f"http://127.0.0.1:{free_port()}"}, "POST")
    assert r.status == 403  # another origin, even with the key (which stays unspent)
    assert request(port, "/enter", {**own, "Authorization": "Bearer e.wrong-key-00.00"}, "POST").status == 403
    r = request(port, "/enter", {"Host": f"localhost:{port}", **enter}, "POST")
    assert r.status == 200 and r.getheader("Set-Cookie") is None
    key = json.loads(r.body)["key"]
    assert request(port, "/enter", {**own, **enter}, "POST").status == 403  # one use
    auth = {"Authorization": f"Bearer {key}"}
    assert request(port, "/settings", {**own, **auth}).status == 200
    assert request(port, "/settings", {"Host": f"evil.example:{port}", **auth}).status == 403
    upgrade = {
        **own,
        "Connection": "Upgrade",
        "Upgrade": "websocket",
        "Sec-WebSocket-Version": "13",
        "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
    }
    assert request(port, f"/ws?key={key}", {**upgrade, "Origin": "http://localhost:8765"}).status == 403
    assert request(port, f"/ws?key={key}", {**upgrade, "Origin": "null"}).status == 403
    return key


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


def serve_dir(directory) -> tuple[http.server.ThreadingHTTPServer, int]:
    handler = partial(QuietHandler, directory=str(directory))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)  # (0: the system's free port, at the bind)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.server_address[1]


def test_only_its_own_pages_reach_the_console_and_no_page_breaks_it(tmp_path):
    from playwright.sync_api import sync_playwright

    run = WebRun(
        tmp_path,
        "edge",
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
        "5",
    )
    evil_dir = tmp_path / "evil"
    evil_dir.mkdir()
    server = None
    try:
        port = port_of(run.url())
        check_raw_http(run.url())
        url = run.another_address()  # (the printed one is spent: each opens one page)
        (evil_dir / "index.html").write_text(INTRUDER.replace("PORT", str(port)))
        server, evil_port = serve_dir(evil_dir)
        with sync_playwright() as pw:
            ctx = browser(pw, tmp_path / "profile", ("--host-resolver-rules=MAP evil.example 127.0.0.1",))
            page = open_console(ctx, url)  # the printed address: one click; the page keeps its key itself
            assert page.url == f"http://127.0.0.1:{port}/" and page.evaluate("hitl.me") == "web-1"

            # Pages of other origins in the same browser: refused, nothing read or steered.
            for where in (
                f"http://127.0.0.1:{evil_port}/index.html",
                f"http://localhost:{evil_port}/index.html",
                (evil_dir / "index.html").as_uri(),
            ):
                intruder = ctx.new_page()
                intruder.goto(where)
                intruder.wait_for_function("window.result && window.result.ws !== 'pending'", timeout=20_000)
                got = intruder.evaluate("window.result")
                assert got["ws"] == "refused" and got["msgs"] == 0, (where, got)
                intruder.close()
            # A rebinding name that resolves to 127.0.0.1: its Host is not the console's.
            rebound = ctx.new_page()
            resp = rebound.goto(f"http://evil.example:{port}/#token={run.another_address().split('=', 1)[1]}")
            assert resp.status == 403 and "Not open to this page" in rebound.content()
            rebound.close()

            # A name of another script: a clear refusal on that page; the console goes on.
            named = ctx.new_page()
            named.goto(with_query(run.another_address(), "name=имя"))
            named.wait_for_function("window.hitl && hitl.refused", timeout=30_000)
            assert "ASCII" in named.locator("#who").inner_text()
            named.close()
            # A number of 400 digits: refused as out of range; the page's socket stays open.
            page.evaluate("""() => hitl.ws.send('{"type": "feedback", "value": 1, "t_page": 1' + '0'.repeat(400) +
                                                ', "offset": 0, "rtt": 0}')""")
            page.wait_for_function("hitl.rejected.bad_value >= 1", timeout=10_000)
            n = page.evaluate("hitl.pongs")
            page.wait_for_timeout(2500)
            assert not page.evaluate("hitl.closed") and page.evaluate("hitl.pongs") > n

            # 20,000 pace controls from one page: a few pass the person's rate limit, the rest are counted.
            flooder = open_console(ctx, run.another_address())
            flooder.evaluate("""() => { for (let i = 0; i < 20000; i++)
                hitl.ws.send(JSON.stringify({type: 'control', command: 'pace', rate: 1 + (i % 50)})); }""")
            flooder.wait_for_function("(hitl.rejected.control_flood || 0) >= 100", timeout=30_000)
            flooder.close()
            # its seat is freed when the console sees the close: before the sockets below fill the console (a
            # loaded run freed it after them, so the late page below took that seat and no silent page was closed)
            page.wait_for_timeout(2000)

            # Sockets that hold every seat and say nothing: the one past the cap is told the console is full,
            # and a real person still gets in (silent pages are closed to make room).
            page.evaluate("""() => { window.held = []; window.heldMsgs = [];
                const key = encodeURIComponent(sessionStorage.getItem("hitl-console-key"));
                for (let i = 0; i < 8; i++) { const ws = new WebSocket(`ws://${location.host}/ws?key=${key}`);
                    ws.onmessage = (ev) => window.heldMsgs.push(JSON.parse(ev.data).type === 'refused'
                        ? JSON.parse(ev.data).reason : 'msg');
                    window.held.push(ws); } }""")
            page.wait_for_function("window.heldMsgs.includes('full')", timeout=20_000)
            page.wait_for_timeout(7000)
            late = open_console(ctx, run.another_address())
            assert late.evaluate("hitl.me").startswith("web-")

            page.click("#end")
            assert run.wait(120) == 0, run.out[-3000:]
            assert page.errors == [] and late.errors == []
            ctx.close()
    finally:
        if server is not None:
            server.shutdown()
        run.close()
    stats = json.loads((run.rundir / "stats" / "teacher.web.json").read_text())["counters"]
    assert stats["door_refused_origin"] >= 3 and stats["door_refused_host"] >= 4, stats
    assert stats["door_refused_no_token"] >= 3 and stats["page_refused_bad_name"] == 1
    assert stats["page_rejected_control_flood"] >= 19_900 and stats.get("page_errors", 0) == 0
    assert stats["page_refused_full"] >= 1 and stats["page_idle_closed"] >= 1
    controls = [r.message for r in read_log(run.rundir / "session.mcap") if isinstance(r.message, Control)]
    assert len([c for c in controls if c.command == "pace"]) <= 20, len(controls)
    people = json.loads((run.rundir / "summary.json").read_text())["people"]
    assert people["web-1"]["dropped"] == {"bad_value": 1}, people  # the 400-digit press, named per person
    assert [c.command for c in controls if c.source.startswith("web")].count("end") == 1
