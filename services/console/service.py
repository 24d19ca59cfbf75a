"""`python -m services.console`: the console, a person in the loop through a browser.

Serves one page (`services/console/static/`, shipped with the package: no CDN, no build step) on
HOST:PORT and bridges it to the run over a WebSocket (`/ws`, aiohttp). Each open page is a teacher of its
own; see `bridge.py` for what flows each way and `people.py` for what a page may send.

Clock: the page estimates its offset to this server as NTP does (`ping` t0 -> `pong` t0, t1, t2; offset
((t1 - t0) + (t2 - t3)) / 2 from the exchange with the smallest round trip) and stamps presses, paints and
webcam frames with its own clock and that offset; the server checks the result against its clock.

Loopback only by default. With `--security` (the run's security.json) the console serves other machines
only after a person gives a teacher name and password that the security file knows.
"""
from __future__ import annotations

import asyncio
import json
import sys
import time
from pathlib import Path

from aiohttp import WSMsgType, web

from common.protocol import teacher_service_name
from services.common.runtime import ServiceRuntime, service_main
from services.console.bridge import Hub
from services.console.config import ConsoleConfig
from services.console.people import PageError, PageGate, Person

STATIC = Path(__file__).resolve().parent / "static"
SEND_QUEUE = 256  # messages waiting for a slow page before the oldest are dropped


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


def check_login(config: ConsoleConfig, request: web.Request) -> str | None:
    """With --security: the teacher name if its password matches the security file, else None."""
    from common.security import load_security

    import hmac

    from common.security import SecurityError

    name, password = request.query.get("teacher", ""), request.query.get("password", "")
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


def make_app(config: ConsoleConfig, rt: ServiceRuntime, hub: Hub) -> web.Application:
    gate = PageGate(config.max_clock_skew, config.max_frame_bytes)

    async def index(request: web.Request) -> web.FileResponse:
        return web.FileResponse(STATIC / "index.html")

    async def settings(request: web.Request) -> web.Response:
        return web.json_response({"login": bool(config.security)})

    async def socket(request: web.Request) -> web.WebSocketResponse:
        name = request.query.get("name") or None
        if config.security:
            name = check_login(config, request)
            if name is None:
                rt.counters["login_refused"] += 1
                raise web.HTTPForbidden(text="teacher name or password not accepted")
        if len(hub.people) >= config.max_people:
            raise web.HTTPServiceUnavailable(text="too many people at this console")
        if name is not None and not all(ch.isalnum() or ch in "_.-" for ch in name[:32]):
            name = None
        ws = web.WebSocketResponse(max_msg_size=config.max_frame_bytes + 64, heartbeat=10.0)
        await ws.prepare(request)
        request.app["sockets"].add(ws)
        page = Page(ws, rt)
        person = hub.join(name[:32] if name else None, page.send)
        writer = asyncio.create_task(page.writer())
        page.send(hub.hello(person))
        if hub.last_step is not None:
            page.send(hub.last_step)
            page.send(hub.preferences())
        try:
            async for msg in ws:
                handle(msg, person, page)
        finally:
            writer.cancel()
            hub.leave(person)
            request.app["sockets"].discard(ws)
        return ws

    def handle(msg, person: Person, page: Page) -> None:
        t1 = time.time()
        try:
            if msg.type == WSMsgType.BINARY:
                hub.frame(person, *gate.frame(msg.data, person))
                return
            if msg.type != WSMsgType.TEXT:
                return
            m = gate.text(msg.data, person)
        except PageError as e:
            rt.counters[f"page_rejected_{e.reason}"] += 1
            page.send({"type": "rejected", "reason": e.reason})
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

    app = web.Application(client_max_size=1 << 20)
    app["sockets"] = set()
    app.router.add_get("/", index)
    app.router.add_get("/ws", socket)
    app.router.add_get("/settings", settings)
    app.router.add_static("/static/", STATIC)
    return app


async def serve(config: ConsoleConfig, rt: ServiceRuntime, session) -> None:
    loop = asyncio.get_running_loop()
    hub = Hub(config, rt, session, loop)
    hub.subscribe()
    app = make_app(config, rt, hub)
    runner = web.AppRunner(app, access_log=None, shutdown_timeout=2.0)
    await runner.setup()
    tls = tls_context(config)
    site = web.TCPSite(runner, config.host, config.port, ssl_context=tls)
    await site.start()
    rt.set_counters_source(lambda: {"people_now": len(hub.people)})
    rt.ready()
    rt.log(f"console: {'https' if tls else 'http'}://{config.host}:{config.port}/")
    stop_at = None
    try:
        last_announce = 0.0
        while not rt.stop.is_set():
            await asyncio.sleep(0.1)
            rt.tick()
            hub.start_when_watched()
            if time.monotonic() - last_announce >= config.status_period:
                hub.announce()
                last_announce = time.monotonic()
            if hub.learner_stopped and stop_at is None:
                stop_at = time.monotonic() + config.stop_after
            if stop_at is not None and time.monotonic() > stop_at:
                break
    finally:
        for person in list(hub.people.values()):
            hub.person_status(person, "stopped")
        for ws in list(app["sockets"]):  # the pages see the run end (and cleanup does not wait for them)
            await ws.close(code=1001, message=b"run over")
        await runner.cleanup()
        hub.close()


def main(config: ConsoleConfig) -> int:
    if config.host not in ("127.0.0.1", "localhost", "::1") and not config.security:
        print(f"error: the console serves {config.host} only with --security (a teacher password per person)",
              file=sys.stderr)
        return 2
    if config.replay:
        from services.console.replay import replay_main

        return replay_main(config)
    rt = ServiceRuntime(teacher_service_name(config.teacher_prefix), config)
    with rt.session() as session:
        asyncio.run(serve(config, rt, session))
    rt.write_stats()
    rt.log(f"stopped: {rt.counters['feedback_published_all']} feedback from {rt.counters['people_joined']} people")
    return 0


STUDIES = ("scripted", "compare", "measure")


def cli(argv: list[str] | None = None) -> int:
    """`python -m services.console --flags` serves the page; `python -m services.console scripted|compare|measure`
    runs a scripted person through it, the declared comparisons of that person, or the console's timing figures."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] and argv[0] in STUDIES:
        from common.config import Command, run_commands
        from services.console import compare, measure, scripted

        studies = {"scripted": Command(scripted.ScriptedConfig, scripted.main),
                   "compare": Command(compare.CompareConfig, compare.main),
                   "measure": Command(measure.MeasureConfig, measure.main)}
        return run_commands("python -m services.console", cli.__doc__, studies, argv)
    return service_main(ConsoleConfig, main, argv, "python -m services.console",
                        also="Also: python -m services.console scripted|compare|measure --help.")
