"""Bounds on the console's sockets before they present a key (aiohttp has no header timeout of its own).

Every accepted connection is wrapped (`SocketGuard.factory`) and tracked until it presents a valid key
(`Door` calls `authenticated`). Until then:

- it must finish a request's headers within `header_timeout` s of opening (a socket sending a header byte a second
  is closed: `door_closed_header_timeout`), and may sit idle between requests at most `idle_timeout` s
  (`door_closed_idle`);
- connections from one client address and in total are capped. At a cap, the oldest connection without a key makes
  room (`door_evicted_address_cap` / `door_evicted_total_cap`): an attacker who holds thousands of idle sockets
  keeps at most the cap, and a person's fresh connection passes. Only when every connection has a key is a new one
  refused (`door_refused_address_cap` / `door_refused_total_cap`).

A sweep once a second closes what is overdue; connections with a key are the page's own (WebSocket idle limits
apply to them, services/console/service.py).
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections import Counter
from collections.abc import Callable, MutableMapping
from dataclasses import dataclass, field
from typing import Any

from services.common.statefiles import atomic_write, port_to_bind

SWEEP_PERIOD = 1.0  # s between sweeps of overdue connections


def listening_socket(host: str, port: int, port_file: str | None) -> tuple[socket.socket, int]:
    """The console's server socket, bound, and its port. Port 0: the port an earlier console of this run wrote to
    `port_file` (a restart: open pages reconnect there), else one the system picks at this bind. Bound here rather
    than probed by the launcher and bound later: in between, another process could take a probed port (a test
    suite's routers did, and the page met a Zenoh router)."""
    port = port_to_bind(port, port_file)
    found = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    family, kind, proto, _, address = found[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # (a restart: the old port may be in TIME_WAIT)
        sock.bind(address)
    except OSError:
        sock.close()
        raise
    bound = sock.getsockname()[1]
    if port_file is not None:
        atomic_write(port_file, str(bound).encode())
    return sock, bound


@dataclass
class Conn:
    address: str
    since: float  # opened, or its latest request finished (monotonic s)
    requests: int = 0  # requests whose headers arrived
    busy: bool = False  # a request is being handled
    authenticated: bool = False
    order: int = 0  # accept order (oldest is evicted first)
    transport: Any = field(default=None, repr=False)


class GuardedProtocol(asyncio.Protocol):
    """aiohttp's protocol for one connection, with the guard told when it opens and closes."""

    def __init__(self, guard: SocketGuard, inner: asyncio.Protocol):
        self.guard, self.inner = guard, inner
        self.admitted, self.transport = False, None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport
        self.admitted = self.guard.admit(transport)
        if self.admitted:
            self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self.admitted:
            self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received() if self.admitted else None

    def connection_lost(self, exc: Exception | None) -> None:
        if self.admitted:
            self.guard.forget(self.transport)
            self.inner.connection_lost(exc)

    def pause_writing(self) -> None:
        if self.admitted:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.admitted:
            self.inner.resume_writing()


class SocketGuard:
    def __init__(
        self,
        counters: MutableMapping[str, int],
        header_timeout: float = 10.0,
        idle_timeout: float = 10.0,
        per_address: int = 64,
        total: int = 256,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.counters, self.clock = counters, clock
        self.header_timeout, self.idle_timeout = header_timeout, idle_timeout
        self.per_address, self.total = per_address, total
        self.conns: dict[int, Conn] = {}  # id(transport) -> its state
        self.by_address: Counter[str] = Counter()
        self._accepted = 0
        self.most = 0  # the most connections held at once

    def factory(self, inner_factory: Callable[[], asyncio.Protocol]) -> Callable[[], asyncio.Protocol]:
        return lambda: GuardedProtocol(self, inner_factory())

    # -- opening and closing -----------------------------------------------------------------------------------
    def admit(self, transport: Any) -> bool:
        peer = transport.get_extra_info("peername")
        address = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        for name, full in (
            ("address", self.by_address[address] >= self.per_address),
            ("total", len(self.conns) >= self.total),
        ):
            if full and not self.evict_oldest(address if name == "address" else None, name):
                self.counters[f"door_refused_{name}_cap"] += 1
                transport.abort()
                return False
        self._accepted += 1
        self.conns[id(transport)] = Conn(address, self.clock(), order=self._accepted, transport=transport)
        self.by_address[address] += 1
        self.most = max(self.most, len(self.conns))
        return True

    def evict_oldest(self, address: str | None, cap: str) -> bool:
        """Close the oldest connection without a key (of `address`, or of anyone): True if there was one."""
        candidates = [c for c in self.conns.values() if not c.authenticated and address in (None, c.address)]
        if not candidates:
            return False
        oldest = min(candidates, key=lambda c: c.order)
        self.counters[f"door_evicted_{cap}_cap"] += 1
        self.drop(oldest)
        return True

    def drop(self, conn: Conn) -> None:
        self.forget(conn.transport)
        conn.transport.abort()

    def forget(self, transport: Any) -> None:
        conn = self.conns.pop(id(transport), None)
        if conn is not None:
            self.by_address[conn.address] -= 1
            if self.by_address[conn.address] <= 0:
                del self.by_address[conn.address]

    # -- what the door tells -----------------------------------------------------------------------------------
    def busy(self, transport: Any, busy: bool) -> None:
        conn = self.conns.get(id(transport))
        if conn is not None:
            conn.busy = busy
            if busy:
                conn.requests += 1
            else:
                conn.since = self.clock()

    def authenticated(self, transport: Any) -> None:
        conn = self.conns.get(id(transport))
        if conn is not None:
            conn.authenticated = True

    # -- the sweep ---------------------------------------------------------------------------------------------
    def sweep(self) -> int:
        """Close every connection without a key that is overdue; returns how many."""
        now, closed = self.clock(), 0
        for conn in list(self.conns.values()):
            if conn.authenticated or conn.busy:
                continue
            limit, reason = (
                (self.header_timeout, "header_timeout") if conn.requests == 0 else (self.idle_timeout, "idle")
            )
            if now - conn.since > limit:
                self.counters[f"door_closed_{reason}"] += 1
                self.drop(conn)
                closed += 1
        return closed

    async def sweeper(self) -> None:
        while True:
            await asyncio.sleep(SWEEP_PERIOD)
            self.sweep()

    def gauges(self) -> dict[str, int]:
        return {
            "connections_now": len(self.conns),
            "connections_most": self.most,
            "connections_without_key": sum(not c.authenticated for c in self.conns.values()),
        }
