"""`python -m services.console`: the console, a person in the loop through a browser.

Serves one page (`services/console/static/`, shipped with the package: no CDN, no build step) on
HOST:PORT and bridges it to the run over a WebSocket (`/ws`, aiohttp). Each open page is a teacher of its
own; see `bridge.py` for what flows each way and `people.py` for what a page may send.

Clock: the page estimates its offset to this server as NTP does (`ping` t0 -> `pong` t0, t1, t2; offset
((t1 - t0) + (t2 - t3)) / 2 from the exchange with the smallest round trip) and stamps presses, paints and
webcam frames with its own clock and that offset; the server checks the result against its clock.

Loopback only by default, and only to its own pages: every request passes the door (`door.py`: Host, Origin, and a
key the page presents itself: no cookie), and a socket that presents no key is bounded in time and number
(`sockets.py`). With `--security` (the run's security.json) the
console serves other machines over HTTPS, and only after a person gives a teacher name and password that the
security file knows. What one page sends or breaks stays with that page (`Pages`).
"""

from __future__ import annotations

import asyncio
import importlib
import json
import re
import sys
import threading
import time
from pathlib import Path

from aiohttp import WSMsgType, web

from common.pathtrace import traced
from common.protocol import teacher_service_name
from services.common.runtime import ServiceRuntime, service_main
from services.console.bridge import Hub
from services.console.config import ConsoleConfig
from services.console.door import Door, Keys, read_or_make_token, spent_file_for
from services.console.people import PageError, PageGate, Person
from services.console.sockets import SocketGuard, listening_socket

STATIC = Path(__file__).resolve().parent / "static"
SEND_QUEUE = 256  # messages waiting for a slow page before the oldest are dropped

PAGE_ID = re.compile(r"^[A-Za-z0-9_-]{8,64}$")  # a page's own id (console.js: one per browser tab)
PERSON_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")  # ?name=: becomes the teacher id <prefix>-<name>
LOOP_PASS = 0.5  # s between two passes of the console's own loop (status, announce, starting the actor)
# Each person's status again every ANNOUNCE_PERIOD s (not the slower status period): a learner that restarts
# drops a press from a teacher it has not yet heard of, so it must hear of them soon.
ANNOUNCE_PERIOD = 2.0


class Page:
    """One WebSocket: a person. Outgoing messages go through a bounded queue (a slow page loses the oldest)."""

    def __init__(self, ws: web.WebSocketResponse, rt: ServiceRuntime):
        self.ws, self.rt = ws, rt
        self.queue: asyncio.Queue = asyncio.Queue(SEND_QUEUE)

    def send(self, payload: dict) -> None:
        if self.queue.full():
            self.queue.get_nowait()
            self.rt.counters["page_send_dropped"] += 1
        self.queue.put_nowait(payload)

    async def writer(self) -> None:
        while True:
            payload = await self.queue.get()
            await self.ws.send_str(json.dumps(payload))


def check_name(name: str | None) -> str | None:
    """`?name=` as given, if it is a safe ASCII name; raises PageError (with the rule) otherwise."""
    if name is None or name == "":
        return None
    if not PERSON_NAME.match(name):
        raise PageError(
            "bad_name", "a name is 1-32 ASCII letters, digits, '_', '.' or '-', starting with a letter or digit"
        )
    return name


def check_page_id(page_id: str | None) -> str | None:
    if page_id is None or page_id == "":
        return None
    if not PAGE_ID.match(page_id):
        raise PageError("bad_value", "page id")
    return page_id


def check_login(config: ConsoleConfig, request: web.Request) -> str | None:
    """With --security: the teacher name if its password matches the security file, else None."""
    from common.security import load_security

    import hmac

    from common.security import SecurityError

    name, password = request.query.get("teacher", ""), request.query.get("password", "")
    if not config.security:
        return None
    security = load_security(config.security)
    try:
        username = security.username("teacher", name)
        ok = bool(name) and hmac.compare_digest(security.password(username).encode(), password.encode())
    except (SecurityError, OSError, ValueError):
        return None
    return name if ok else None


def tls_context(config: ConsoleConfig):
    """With --security on the router's machine: HTTPS with the router's certificate (the run's CA signs it),
    so a password never crosses the network in clear text. None otherwise."""
    import ssl

    from common.security import load_security

    if not config.security:
        return None
    security = load_security(config.security)
    if not (security.router_cert and security.router_key):
        return None
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.load_cert_chain(security.path(security.router_cert), security.path(security.router_key))
    return ctx


class Pages:
    """The WebSocket side: one `socket` per page; whatever one page sends or breaks stays with that page."""

    def __init__(self, config: ConsoleConfig, rt: ServiceRuntime, hub: Hub):
        self.config, self.rt, self.hub = config, rt, hub
        self.gate = PageGate(config.max_clock_skew, config.max_frame_bytes)
        self.sockets: set[web.WebSocketResponse] = set()

    async def refuse(self, ws: web.WebSocketResponse, reason: str, why: str, code: int) -> web.WebSocketResponse:
        """An open WebSocket refused with a sentence the page shows (a failed upgrade tells a page nothing)."""
        self.rt.counters[f"page_refused_{reason}"] += 1
        await ws.send_json({"type": "refused", "reason": reason, "why": why})
        await ws.close(code=code, message=reason.encode())
        return ws

    async def socket(self, request: web.Request) -> web.WebSocketResponse:
        config, rt, hub = self.config, self.rt, self.hub
        # compress=False: aiohttp deflates every frame a page accepts compressed, a sixth of the console's work in a
        # paced run (py-spy) for messages of a few hundred bytes
        ws = web.WebSocketResponse(max_msg_size=config.max_frame_bytes + 64, heartbeat=10.0, compress=False)
        await ws.prepare(request)
        try:
            name, page_id = check_name(request.query.get("name")), check_page_id(request.query.get("page"))
        except PageError as e:
            return await self.refuse(ws, e.reason, f"not accepted: {e.detail}", 4400)
        if config.security:
            name = check_login(config, request)
            if name is None:
                rt.counters["login_refused"] += 1
                return await self.refuse(ws, "login", "teacher name or password not accepted", 4403)
        make_room(config, hub, rt)
        if len(hub.people) >= config.max_people:
            return await self.refuse(
                ws,
                "full",
                f"the console is full ({config.max_people} people are teaching); try again when someone leaves",
                1013,
            )
        page = Page(ws, rt)
        try:
            person = hub.join(name, page_id, page.send)
        except Exception as exc:  # (one page's join must not stop the console)
            rt.counters["page_errors"] += 1
            rt.event(f"a page could not join: {exc!r}", 3)
            return await self.refuse(ws, "error", "the console could not add you; see its log", 1011)
        person.close = lambda: asyncio.ensure_future(ws.close(code=1001, message=b"idle"))
        self.sockets.add(ws)
        writer = asyncio.create_task(page.writer())
        try:
            page.send(hub.hello(person))
            if hub.last_step is not None:
                page.send(hub.last_step)
                page.send(hub.preferences())
            await self.read_page(ws, person, page)
        except Exception as exc:  # anything one page caused closes that page only, counted
            rt.counters["page_errors"] += 1
            rt.event(f"page of {person.teacher_id} closed after an error: {exc!r}", 3)
            await ws.close(code=1011, message=b"error")
        finally:
            writer.cancel()
            hub.leave(person)
            self.sockets.discard(ws)
        return ws

    async def read_page(self, ws: web.WebSocketResponse, person: Person, page: Page) -> None:
        while True:
            try:
                msg = await ws.receive(timeout=self.config.idle_timeout)
            except TimeoutError:  # a page pings every 2 s: this one is gone or idle
                self.rt.counters["page_idle_closed"] += 1
                await ws.close(code=1001, message=b"idle")
                return
            if msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSING, WSMsgType.CLOSED, WSMsgType.ERROR):
                return
            person.last_heard = time.monotonic()
            self.handle(msg, person, page)

    @traced("console.page")
    def handle(self, msg, person: Person, page: Page) -> None:
        hub, t1 = self.hub, time.time()
        try:
            if msg.type == WSMsgType.BINARY:
                hub.frame(person, *self.gate.frame(msg.data, person))
                return
            if msg.type != WSMsgType.TEXT:
                return
            m = self.gate.text(msg.data, person)
        except PageError as e:
            self.rt.counters[f"page_rejected_{e.reason}"] += 1
            if e.kind == "feedback":
                hub.press_dropped(person, e.reason)
            page.send({"type": "rejected", "reason": e.reason, "press": e.press})
            return
        if m["type"] == "ping":
            person.clock_ready = person.clock_ready or m["ready"]
            page.send({"type": "pong", "t0": m["t0"], "t1": t1, "t2": time.time()})
        elif m["type"] == "shown":
            hub.shown(person, m)
        elif m["type"] == "feedback":
            page.send(hub.feedback(person, m))
        else:
            hub.control(person, m)


def make_app(config: ConsoleConfig, pages: Pages, door: Door) -> web.Application:
    async def index(request: web.Request) -> web.FileResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def settings(request: web.Request) -> web.Response:
        return web.json_response({"login": bool(config.security)})

    async def invite(request: web.Request) -> web.Response:  # another one-use address, for another tab or person
        pages.rt.counters["door_invited"] += 1
        return web.json_response({"address": door.address()}, headers={"Cache-Control": "no-store"})

    app = web.Application(client_max_size=1 << 20, middlewares=[door.middleware])
    app.router.add_get("/", index)
    app.router.add_get("/ws", pages.socket)
    app.router.add_get("/settings", settings)
    app.router.add_post("/invite", invite)
    app.router.add_post("/enter", invite)  # (answered by the door; this route only makes POST /enter reach it)
    app.router.add_static("/static/", STATIC)
    return app


def make_room(config: ConsoleConfig, hub: Hub, rt: ServiceRuntime) -> None:
    """A full console first closes pages silent for 3 ping periods (6 s): held sockets never lock a person out."""
    if len(hub.people) < config.max_people:
        return
    now = time.monotonic()
    for person in list(hub.people.values()):
        if now - person.last_heard > 6.0 and person.close is not None:
            rt.counters["page_idle_closed"] += 1
            hub.leave(person)  # its seat is free now; its socket closes in the background
            person.close()


async def serve(config: ConsoleConfig, rt: ServiceRuntime, session) -> None:
    loop = asyncio.get_running_loop()
    hub = Hub(config, rt, session, loop)
    hub.subscribe()
    tls = tls_context(config)
    scheme = "https" if tls else "http"
    guard = SocketGuard(
        rt.counters,
        config.header_timeout,
        config.unauthenticated_idle,
        config.max_connections_per_address,
        config.max_connections,
    )
    keys = Keys(read_or_make_token(config.token_file), spent_file_for(config.token_file))
    sock, port = listening_socket(config.host, config.port, config.port_file)  # (the door checks Host: the real port)
    door = Door(keys, config.host, port, scheme, rt.counters, config.server_names, guard)
    pages = Pages(config, rt, hub)
    app = make_app(config, pages, door)
    runner = web.AppRunner(app, access_log=None, shutdown_timeout=2.0)
    await runner.setup()
    assert runner.server is not None
    server = await loop.create_server(guard.factory(runner.server), sock=sock, ssl=tls, backlog=1024)
    sweeper = asyncio.create_task(guard.sweeper())
    rt.set_counters_source(lambda: {"people_now": len(hub.people), **guard.gauges()})
    rt.ready()
    # listening now; this log is private to the run's user (0600 in a 0700 run folder), like the terminal
    rt.log(f"console: {door.address()}")
    stop_at = None
    try:
        last_announce = 0.0
        while not rt.stop.is_set():
            await asyncio.sleep(LOOP_PASS)
            rt.tick()
            hub.start_when_watched()
            if time.monotonic() - last_announce >= ANNOUNCE_PERIOD:
                hub.announce()
                last_announce = time.monotonic()
            if hub.learner_stopped and stop_at is None:
                stop_at = time.monotonic() + config.stop_after
            if stop_at is not None and time.monotonic() > stop_at:
                break
    finally:
        for person in list(hub.people.values()):
            hub.person_status(person, "stopped")
        for ws in list(pages.sockets):  # the pages see the run end (and cleanup does not wait for them)
            await ws.close(code=1001, message=b"run over")
        sweeper.cancel()
        server.close()
        await runner.cleanup()
        hub.close()


def main(config: ConsoleConfig) -> int:
    if config.host not in ("127.0.0.1", "localhost", "::1") and not config.security:
        print(
            f"error: the console serves {config.host} only with --security (a teacher password per person)",
            file=sys.stderr,
        )
        return 2
    if config.replay:
        from services.console.replay import replay_main

        return replay_main(config)
    # torch (the agent showing Q and H) takes seconds to import: while the Zenoh session opens, not after it, so
    # a restarted console is back for its pages sooner (issue 33)
    threading.Thread(target=importlib.import_module, args=("common.agents.torch_agent",), daemon=True).start()
    rt = ServiceRuntime(teacher_service_name(config.teacher_prefix), config)
    with rt.session() as session:
        asyncio.run(serve(config, rt, session))
    rt.write_stats()
    rt.log(f"stopped: {rt.counters['feedback_published_all']} feedback from {rt.counters['people_joined']} people")
    return 0


STUDIES = ("scripted", "compare", "people", "measure")


def cli(argv: list[str] | None = None) -> int:
    """`python -m services.console --flags` serves the page; `python -m services.console
    scripted|compare|people|measure` runs a scripted person through it, the declared comparisons of that person, the
    check of those runs' pace and presses, or the console's timing figures."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] and argv[0] in STUDIES:
        from common.config import Command, run_commands
        from services.console import compare, compare_people, measure, scripted

        studies = {
            "scripted": Command(scripted.ScriptedConfig, scripted.main),
            "compare": Command(compare.CompareConfig, compare.main),
            "people": Command(compare_people.PeopleConfig, compare_people.main),
            "measure": Command(measure.MeasureConfig, measure.main),
        }
        return run_commands("python -m services.console", cli.__doc__ or "", studies, argv)
    return service_main(
        ConsoleConfig,
        main,
        argv,
        "python -m services.console",
        also="Also: python -m services.console scripted|compare|people|measure --help.",
    )
