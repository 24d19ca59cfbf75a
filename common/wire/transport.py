"""Zenoh session helpers for the live services: loopback configs, sessions that always close, publishers declared
with the right congestion control, and callback subscribers feeding bounded inboxes (the publisher and the inbox
a service uses for each message are in common/wire/delivery.py, re-exported here).

Facts this module relies on (zenoh-python 1.10, measured here; see docs/protocol.md for the keys):

- A client whose router is not up fails in ``zenoh.open`` at once unless ``connect/timeout_ms`` is set;
  with it, ``open`` retries (period from ``connect/retry``) and returns as soon as it connects.
- ``connect/retry`` must be inserted as a whole object; inserting ``connect/retry/period_init_ms`` alone
  fails with "unknown key" because the default is null.
- ``sample.timestamp`` is None unless ``timestamping/enabled`` is on; all configs here turn it on.
- ``Publisher.matching_status`` is an object with ``.matching`` (not a bool, whatever the stub says).
- A subscriber declared before a router link is up misses what is published before its declaration reaches
  the publisher's side: wait with :func:`wait_for_matching` before the first message that matters.
- A process whose callback subscriber is still declared at exit hangs unless the session is closed:
  :func:`open_session` closes in ``finally``.

Run a router on its own: ``python -m services router --port 7447`` (prints ``ready <endpoint>``,
stops on SIGTERM/SIGINT).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import signal
import socket
import threading
import time
from typing import Any
from collections.abc import Callable, Iterator

import zenoh

from common.wire.delivery import (  # (re-exported: a service opens its session and its publishers here)
    QUEUE_POLICIES,  # noqa: F401
    Forward,
    Inbox,
    MessagePublisher,  # noqa: F401
    Received,
    default_policy,
    set_default_auth,  # noqa: F401
)
from common.config import option
from common.protocol import parse_key

LOOPBACK = "127.0.0.1"
DEFAULT_CONNECT_TIMEOUT = 10.0  # seconds a client keeps trying to reach its router in open()


# -- configs ---------------------------------------------------------------------------------------------------


def free_port(host: str = LOOPBACK) -> int:
    """A TCP port that was free a moment ago (bind to port 0, read it, close). Racy but fine on loopback."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class PortInUse(ValueError):
    """A port asked for by number is taken; the message names it and what to do."""


def open_listening(
    config_for: Callable[[int], zenoh.Config], port: int, host: str = LOOPBACK
) -> tuple[zenoh.Session, int]:
    """A session listening on `port` (its config from `config_for(port)`), and the port. Port 0: a free port, probed
    (zenoh does not say which port a `:0` listener took) and tried again with another if a process took it between
    the probe and the bind. A port given by number that is taken: `PortInUse`, naming it."""
    for _ in range(1 if port else 5):
        tried = port or free_port(host)
        try:
            return zenoh.open(config_for(tried)), tried
        except zenoh.ZError as exc:
            if "Address already in use" not in str(exc):
                raise
    if port:
        raise PortInUse(f"port {port} on {host} is in use: choose another --port, or 0 for a free one") from None
    raise PortInUse(f"no free port on {host} after 5 tries")


def tcp_endpoint(port: int, host: str = LOOPBACK) -> str:
    return f"tcp/{host}:{int(port)}"


def _as_endpoint(port_or_endpoint: int | str) -> str:
    return tcp_endpoint(port_or_endpoint) if isinstance(port_or_endpoint, int) else port_or_endpoint


# Zenoh's threads in a process with one link (a service: a client of the launcher's router), given to Zenoh in
# the ZENOH_RUNTIME environment variable before its first session (the launcher sets it for its children). By
# default a process runs two rx threads and apart accept and net threads: each received message woke both rx
# threads in turn (measured: docs/notes/2026-11-28-idle-cost.md, third round). One link needs one rx thread;
# accept and net (a client listens on nothing) run on the app thread. The launcher's own process, the router
# with a link per service, keeps Zenoh's defaults.
SERVICE_ZENOH_RUNTIME = "(rx: (worker_threads: 1), acc: (handover: app), net: (handover: app))"

BLOCK_WAIT_US = 20_000_000
"""How long (µs) a BLOCK message may wait for room before Zenoh closes the link (see `make_config`)."""


def make_config(
    mode: str,
    *,
    listen: list[str] | tuple[str, ...] = (),
    connect: list[str] | tuple[str, ...] = (),
    connect_timeout: float | None = None,
    timestamping: bool = True,
) -> zenoh.Config:
    """A closed-world config: no multicast scouting, no gossip, only the given endpoints.

    ``connect_timeout`` (s): how long ``open`` keeps retrying the connect endpoints (None: zenoh's default,
    which for a client is to fail at once)."""
    if mode not in ("router", "peer", "client"):
        raise ValueError(f"mode {mode!r}")
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps(list(listen)))
    c.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if connect_timeout is not None:
        c.insert_json5("connect/timeout_ms", str(int(connect_timeout * 1000)))
        c.insert_json5("connect/retry", "{period_init_ms: 100, period_max_ms: 1000, period_increase_factor: 2}")
    c.insert_json5("timestamping/enabled", "true" if timestamping else "false")
    # A BLOCK message that waits this long for room closes Zenoh's link, losing what was queued on it (Zenoh's
    # default: 5 s). Our inboxes wait up to 5 s themselves and then drop and count (common.wire.delivery): the
    # link must outwait them, or a receiver stalled under load loses messages that nobody counts (seen once:
    # three Ingest batches missing from a flooded, loaded run's log).
    c.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", str(BLOCK_WAIT_US))
    # Zenoh's shared memory is on by default; its thread wakes about 20 times a second in every process even when
    # nothing moves (measured: docs/notes/2026-11-28-idle-cost.md). Our messages are small and go over TCP.
    c.insert_json5("transport/shared_memory/enabled", "false")
    return c


def router_config(port_or_endpoint: int | str, *, timestamping: bool = True) -> zenoh.Config:
    """A Python session acting as the router (no zenohd needed), listening on tcp/127.0.0.1:PORT."""
    return make_config("router", listen=[_as_endpoint(port_or_endpoint)], timestamping=timestamping)


def client_config(
    *endpoints: int | str, connect_timeout: float = DEFAULT_CONNECT_TIMEOUT, timestamping: bool = True
) -> zenoh.Config:
    """A client of the router(s) at ``endpoints`` (ports or ``tcp/host:port``); waits up to
    ``connect_timeout`` s in open() for one to be up."""
    if not endpoints:
        raise ValueError("client_config needs at least one router endpoint")
    return make_config(
        "client",
        connect=[_as_endpoint(e) for e in endpoints],
        connect_timeout=connect_timeout,
        timestamping=timestamping,
    )


def peer_config(
    *,
    listen: list[int | str] | tuple = (),
    connect: list[int | str] | tuple = (),
    connect_timeout: float | None = DEFAULT_CONNECT_TIMEOUT,
    timestamping: bool = True,
) -> zenoh.Config:
    """A peer that listens and/or connects to explicit endpoints (no router needed for two processes)."""
    return make_config(
        "peer",
        listen=[_as_endpoint(e) for e in listen],
        connect=[_as_endpoint(e) for e in connect],
        connect_timeout=connect_timeout if connect else None,
        timestamping=timestamping,
    )


# -- sessions ------------------------------------------------------------------------------------------------------


@contextlib.contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    """Open a session and always close it, even on exceptions (an unclosed session with a callback
    subscriber keeps the process from exiting)."""
    session = zenoh.open(config)
    try:
        yield session
    finally:
        session.close()


def wait_for_router(session: zenoh.Session, timeout: float = 5.0) -> bool:
    """True once the session sees a router (for clients and peers connected to one)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if list(session.info.routers_zid()):
            return True
        time.sleep(0.01)
    return False


def _congestion(name: str) -> zenoh.CongestionControl:
    return zenoh.CongestionControl.BLOCK if name == "block" else zenoh.CongestionControl.DROP


def declare_publisher(
    session: zenoh.Session, key: str, *, congestion: str | None = None, express: bool = False
) -> zenoh.Publisher:
    """A publisher on a concrete protocol key, with congestion control from the key table (BLOCK for config,
    step, feedback, weights, episode; DROP for status, camera, perception) unless ``congestion`` says."""
    spec = parse_key(key).spec
    cls = spec.message
    json_encoded = cls.MESSAGE_ENCODING == "json"
    encoding = zenoh.Encoding.APPLICATION_JSON if json_encoded else zenoh.Encoding.APPLICATION_OCTET_STREAM
    return session.declare_publisher(
        key,
        congestion_control=_congestion(congestion or spec.congestion),
        encoding=encoding.with_schema(cls.TYPE_NAME),
        express=express,
    )


def wait_for_matching(publisher: zenoh.Publisher, timeout: float = 5.0) -> bool:
    """True once at least one subscriber matches the publisher's key."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status: Any = publisher.matching_status  # an object with .matching, not the bool zenoh's stub says
        if status.matching:
            return True
        time.sleep(0.01)
    return False


# -- receiving -------------------------------------------------------------------------------------------------------


def subscribe(
    session: zenoh.Session,
    key_expr: str,
    inbox: Inbox | None = None,
    *,
    maxsize: int = 1024,
    policy: str | None = None,
    block_timeout: float = 5.0,
    auth: Any = None,
) -> tuple[zenoh.Subscriber, Inbox]:
    """Declare a callback subscriber feeding an :class:`Inbox` (a new one unless given), held open beyond a
    ``with`` block (else use :func:`subscription`).

    Undeclare the subscriber (or close the session) and ``inbox.close()`` when done."""
    if inbox is None:
        inbox = Inbox(maxsize, policy or default_policy(key_expr), block_timeout=block_timeout, auth=auth)
    sub = session.declare_subscriber(key_expr, inbox.handler())
    return sub, inbox


@contextlib.contextmanager
def subscriptions(
    session: zenoh.Session,
    key_exprs: list[str],
    *,
    maxsize: int = 1024,
    policy: str | None = None,
    block_timeout: float = 5.0,
    auth: Any = None,
    deliver: Callable[[Received], None] | None = None,
) -> Iterator[Inbox]:
    """``with subscriptions(session, [key, ...]) as inbox: ...``: callback subscribers feeding one Inbox (in arrival
    order; policy by default the key table's for the first key); on exit the inbox is closed first (releasing a
    callback blocked on a full queue), then the subscribers are undeclared. With ``deliver``, the samples go to it
    instead of a queue (:class:`Forward`: the console's event loop)."""
    inbox = (
        Forward(deliver, auth=auth)
        if deliver is not None
        else Inbox(maxsize, policy or default_policy(key_exprs[0]), block_timeout=block_timeout, auth=auth)
    )
    subs = []
    try:
        subs = [session.declare_subscriber(k, inbox.handler()) for k in key_exprs]
        yield inbox
    finally:
        inbox.close()
        for sub in subs:
            with contextlib.suppress(Exception):
                sub.undeclare()


def subscription(session: zenoh.Session, key_expr: str, **kwargs: Any) -> contextlib.AbstractContextManager[Inbox]:
    """``with subscription(session, run_prefix(run)) as inbox: ...``: :func:`subscriptions` of one key."""
    return subscriptions(session, [key_expr], **kwargs)


# -- a router process -----------------------------------------------------------------------------------------------


def run_router(
    endpoint: str, *, stop: threading.Event | None = None, on_ready: Callable[[zenoh.Session], None] | None = None
) -> None:
    """Run a router session on ``endpoint`` until ``stop`` is set (or SIGTERM/SIGINT in the main thread)."""
    stop = stop or threading.Event()
    # The handler only records the signal: calling stop.set() from a handler that interrupted
    # stop.wait() in the same thread deadlocks on the Event's internal lock.
    signalled: list[int] = []
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda signum, _frame: signalled.append(signum))
    with open_session(router_config(endpoint)) as session:
        if on_ready is not None:
            on_ready(session)
        while not signalled and not stop.is_set():
            time.sleep(0.1)


@dataclasses.dataclass(frozen=True)
class RouterConfig:
    """Run a loopback Zenoh router (a Python zenoh session in router mode); prints 'ready <endpoint> <zid>',
    stops on SIGTERM/SIGINT."""

    port: int = option(7447, "listen port on 127.0.0.1")
    endpoint: str | None = option(None, "full endpoint instead of --port, e.g. tcp/0.0.0.0:7447")


def router_main(config: RouterConfig) -> int:
    endpoint = config.endpoint or tcp_endpoint(config.port)

    def ready(session: zenoh.Session) -> None:
        print(f"ready {endpoint} {session.zid()}", flush=True)

    run_router(endpoint, on_ready=ready)
    return 0


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services router")
