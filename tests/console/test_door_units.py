"""The console's door without a browser (issue 33): keys instead of a cookie, one-use entry keys, the secret's
file, and the socket guard's bounds on real loopback sockets (header timeout, idle timeout, caps with eviction)."""

from __future__ import annotations

import asyncio
import collections
import json
import os
import socket

from aiohttp import web
from aiohttp.test_utils import make_mocked_request

from services.console.door import Door, Keys, console_address, read_or_make_token, spent_file_for
from services.console.sockets import SocketGuard, listening_socket

SECRET = "t" * 32


async def _ok(request):
    return web.Response(text="run data")


async def _settings(request):
    return web.json_response({"login": False})


async def through(door: Door, path: str, headers: dict, method: str = "GET") -> web.StreamResponse:
    return await door.middleware(make_mocked_request(method, path, headers=headers), _ok)


def test_the_door_checks_host_origin_and_a_key_on_every_request_and_sets_no_cookie():
    asyncio.run(door_checks())


async def door_checks() -> None:
    counters: collections.Counter = collections.Counter()
    keys = Keys(SECRET)
    door = Door(keys, "127.0.0.1", 8765, "http", counters)
    own = {"Host": "127.0.0.1:8765"}
    page = await through(door, "/", own)  # the page itself: shipped files, no key needed
    assert page.status == 200 and "Set-Cookie" not in page.headers
    for path in ("/settings", "/ws", "/timeline.json", "/invite"):
        assert (await through(door, path, own)).status == 403, path
    entry = keys.entry()
    entered = await through(door, "/enter", {**own, "Authorization": f"Bearer {entry}"}, "POST")
    assert entered.status == 200 and "Set-Cookie" not in entered.headers
    assert isinstance(entered, web.Response) and isinstance(entered.body, bytes)
    key = json.loads(entered.body)["key"]
    again = await through(door, "/enter", {**own, "Authorization": f"Bearer {entry}"}, "POST")
    assert isinstance(again, web.Response) and isinstance(again.body, bytes)
    assert again.status == 403 and b"used already" in again.body  # one use
    auth = {"Authorization": f"Bearer {key}"}
    assert (await through(door, "/settings", {**own, **auth})).status == 200
    assert (await through(door, "/settings", {"Host": "[::1]:8765", **auth})).status == 200
    assert (await through(door, f"/ws?key={key}", {**own, "Origin": "http://127.0.0.1:8765"})).status == 200
    assert (await through(door, f"/settings?key={key}", own)).status == 403  # a query key only on the socket
    for bad in (
        {"Host": "evil.example:8765"},
        {"Host": "127.0.0.1:9999"},
        {"Host": "127.0.0.1"},
        {**own, "Origin": "http://127.0.0.1:9999"},
        {**own, "Origin": "null"},
        {**own, "Origin": "https://127.0.0.1:8765"},
    ):
        assert (await through(door, "/settings", {**bad, **auth})).status == 403, bad
    forged = "s." + key.split(".")[1] + "." + "0" * 32
    assert (await through(door, "/settings", {**own, "Authorization": f"Bearer {forged}"})).status == 403
    assert (await through(door, "/settings", {**own, "Authorization": f"Bearer {entry}"})).status == 403
    other = Keys("u" * 32).session()  # another run's key
    assert (await through(door, "/settings", {**own, "Authorization": f"Bearer {other}"})).status == 403
    assert counters["door_refused_host"] == 3 and counters["door_refused_origin"] == 3
    assert counters["door_refused_no_token"] == 5 and counters["door_refused_token"] == 3
    assert counters["door_refused_spent"] == 1 and counters["door_entered"] == 1
    wild = Door(keys, "0.0.0.0", 8443, "https", counters, ("Lab-PC.example",))
    assert wild.hosts == {"127.0.0.1:8443", "localhost:8443", "[::1]:8443", "lab-pc.example:8443"}
    assert console_address("http", "::1", 80, entry) == f"http://[::1]:80/#token={entry}"


def test_the_secret_is_private_and_a_spent_key_stays_spent_across_a_restart(tmp_path):
    path = tmp_path / "state" / "console.token"
    secret = read_or_make_token(str(path))
    assert len(secret) >= 24 and os.stat(path).st_mode & 0o777 == 0o600
    assert read_or_make_token(str(path)) == secret
    assert read_or_make_token(None) != read_or_make_token(None)
    keys = Keys(secret, spent_file_for(str(path)))
    entry, session = keys.entry(), keys.session()
    assert keys.spend(entry) == "ok" and keys.spend(entry) == "spent" and keys.spend("e.x.y") == "bad"
    assert os.stat(str(spent_file_for(str(path)))).st_mode & 0o777 == 0o600
    restarted = Keys(read_or_make_token(str(path)), spent_file_for(str(path)))  # a restarted console
    assert restarted.spend(entry) == "spent" and restarted.valid("s", session)
    assert restarted.spend(restarted.entry()) == "ok"


def test_the_guard_bounds_sockets_without_a_key_and_a_person_still_gets_in():
    asyncio.run(guard_checks())


async def _open(port: int, n: int) -> list[tuple[asyncio.StreamReader, asyncio.StreamWriter]]:
    return [await asyncio.open_connection("127.0.0.1", port) for _ in range(n)]


async def _closed(reader: asyncio.StreamReader, timeout: float = 0.2) -> bool:
    try:
        return await asyncio.wait_for(reader.read(1), timeout) == b""
    except TimeoutError:
        return False
    except ConnectionError:
        return True


async def _get(port: int, key: str | None) -> int:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    auth = f"Authorization: Bearer {key}\r\n" if key else ""
    writer.write(f"GET /settings HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{auth}\r\n".encode())
    status = int((await asyncio.wait_for(reader.readline(), 10)).split()[1])
    writer.close()
    return status


async def guard_checks() -> None:
    counters: collections.Counter = collections.Counter()
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    guard = SocketGuard(counters, header_timeout=1.5, idle_timeout=1.5, per_address=20, total=30)
    keys = Keys(SECRET)
    door = Door(keys, "127.0.0.1", port, "http", counters, guard=guard)
    app = web.Application(middlewares=[door.middleware])
    app.router.add_get("/settings", _settings)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    assert runner.server is not None
    server = await asyncio.get_running_loop().create_server(guard.factory(runner.server), sock=sock)
    sweeper = asyncio.create_task(guard.sweeper())
    try:
        held = await _open(port, 50)  # an attacker's idle sockets: past the cap, the oldest make room
        await asyncio.sleep(0.3)
        assert len(guard.conns) == 20 and counters["door_evicted_address_cap"] == 30
        assert [await _closed(r) for r, _ in held[:30]] == [True] * 30
        key = keys.session()
        assert await _get(port, key) == 200  # a person's request passes while the attacker holds the cap
        assert counters["door_evicted_address_cap"] == 31
        slow = held[-1][1]
        for byte in b"GET":  # a header byte at a time: still closed at the header timeout
            slow.write(bytes([byte]))
            await asyncio.sleep(0.5)
        await asyncio.sleep(1.5)
        closed = [await _closed(r) for r, _ in held]
        assert all(closed) and len(guard.conns) == 0, ([i for i, c in enumerate(closed) if not c], counters)
        assert counters["door_closed_header_timeout"] == 19, counters
        refused = await _open(port, 1)  # a refused request, then idle: closed at the idle timeout
        refused[0][1].write(f"GET /settings HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
        assert b"403" in await asyncio.wait_for(refused[0][0].readline(), 10)
        await asyncio.sleep(3.0)
        assert counters["door_closed_idle"] == 1 and len(guard.conns) == 0
        assert guard.gauges()["connections_most"] == 20
    finally:
        sweeper.cancel()
        server.close()
        await runner.cleanup()


def test_the_console_binds_its_own_free_port_and_a_restart_binds_the_same(tmp_path):
    """Port 0: the console's bind picks the port (no probe a second process could take first) and writes it for
    the launcher; a restarted console reads it back, so that open pages reconnect; a damaged file is a fresh pick."""
    port_file = tmp_path / "state" / "teacher.web.port"
    sock, port = listening_socket("127.0.0.1", 0, str(port_file))
    assert port > 0 and sock.getsockname()[1] == port and port_file.read_text() == str(port)
    sock.listen()
    with socket.create_connection(("127.0.0.1", port), timeout=5):
        pass
    sock.close()
    again, port_again = listening_socket("127.0.0.1", 0, str(port_file))  # (the old one's port may be in TIME_WAIT)
    assert port_again == port
    other, other_port = listening_socket("127.0.0.1", 0, None)  # while `again` holds it, a fresh pick is another
    assert other_port not in (0, port)
    other.close()
    again.close()
    port_file.write_text("not a port")
    fresh, fresh_port = listening_socket("127.0.0.1", 0, str(port_file))
    assert fresh_port > 0 and port_file.read_text() == str(fresh_port)
    fresh.close()
    given, given_port = listening_socket("127.0.0.1", fresh_port, None)  # a port the user chose is bound as is
    assert given_port == fresh_port
    given.close()
