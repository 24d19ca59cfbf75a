"""Transport: configs, the Inbox policies, and a real router + two client processes on loopback."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from common.protocol import ServiceStatus, Step, status_key, step_key
from common.wire.transport import (
    LOOPBACK,
    Inbox,
    MessagePublisher,
    PortInUse,
    Received,
    client_config,
    declare_publisher,
    default_policy,
    free_port,
    open_listening,
    open_session,
    peer_config,
    router_config,
    subscribe,
    subscription,
    tcp_endpoint,
    wait_for_router,
)

from .strategies import example

ROOT = Path(__file__).resolve().parents[2]
PEER = Path(__file__).with_name("zenoh_peer.py")


def item(i: int) -> Received:
    return Received("hitl/r1/step", str(i).encode(), time.time(), None)


# -- Inbox ------------------------------------------------------------------------------------------------------------


def test_inbox_drop_oldest_counts():
    q = Inbox(3, "drop_oldest")
    for i in range(5):
        assert q.put(item(i))
    assert [x.data for x in q.drain()] == [b"2", b"3", b"4"]
    assert q.counters["dropped_oldest"] == 2 and q.counters["received"] == 5


def test_inbox_block_waits_for_room_then_gives_up():
    q = Inbox(1, "block", block_timeout=0.2)
    q.put(item(0))
    t = time.monotonic()
    assert not q.put(item(1))  # full for the whole timeout
    assert 0.15 < time.monotonic() - t < 2
    assert q.counters["dropped_full"] == 1
    # a consumer making room unblocks the producer
    threading.Timer(0.05, q.get).start()
    q.block_timeout = 5.0
    t = time.monotonic()
    assert q.put(item(2))
    assert time.monotonic() - t < 2
    assert q.get(0).data == b"2"


def test_inbox_close_wakes_everyone():
    q = Inbox(1, "block", block_timeout=30)
    q.put(item(0))
    results = []
    th = threading.Thread(target=lambda: results.append(q.put(item(1))))
    th.start()
    time.sleep(0.05)
    q.close()
    th.join(2)
    assert results == [False] and q.counters["dropped_closed"] == 1
    assert q.get(0).data == b"0" and q.get(None) is None  # closed and empty: no wait


def test_inbox_get_message_counts_bad_payloads():
    q = Inbox(10)
    q.put(Received(step_key("r1"), b"{bad", 0.0, None))
    q.put(Received(step_key("r1"), example(Step, run="other").encode(), 0.0, None))
    q.put(Received("hitl/r1/what", b"{}", 0.0, None))
    q.put(Received(step_key("r1"), example(Step).encode(), 0.0, None))
    received, msg = q.get_message(timeout=0)
    assert msg == example(Step)
    assert q.get_message(timeout=0.01) is None
    c = q.snapshot()
    assert (c["dropped_malformed"], c["dropped_bad_value"], c["dropped_unknown_key"], c["decoded"]) == (1, 1, 1, 1)


def test_default_policies():
    assert default_policy("hitl/r1/step") == "block"
    assert default_policy("hitl/r1/feedback/*") == "block"
    assert default_policy("hitl/r1/status/learner") == "drop_oldest"
    assert default_policy("hitl/r1/camera/cam0") == "drop_oldest"
    assert default_policy("hitl/r1/**") == "block"


def test_configs_are_loopback_only():
    port = free_port()
    r = router_config(port)
    assert json.loads(r.get_json("mode")) == "router"
    assert json.loads(r.get_json("listen/endpoints")) == [tcp_endpoint(port)]
    c = client_config(port)
    assert json.loads(c.get_json("connect/endpoints")) == [f"tcp/127.0.0.1:{port}"]
    for cfg in (r, c, peer_config(listen=[port])):
        assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
        assert json.loads(cfg.get_json("scouting/gossip/enabled")) is False
        assert json.loads(cfg.get_json("timestamping/enabled")) is True


# -- in one process -----------------------------------------------------------------------------------------------


def test_in_process_router_and_clients_with_drop_and_block_publishers():
    port = free_port()
    with (
        open_session(router_config(port)) as _router,
        open_session(client_config(port)) as a,
        open_session(client_config(port)) as b,
    ):
        assert wait_for_router(a) and wait_for_router(b)
        sub, inbox = subscribe(b, "hitl/r1/**")
        try:
            steps = MessagePublisher(a, step_key("r1"))
            status = MessagePublisher(a, status_key("r1", "actor"))
            assert steps.wait_for_subscribers(5) and status.wait_for_subscribers(5)
            assert str(steps.publisher.congestion_control).endswith("BLOCK")
            assert str(status.publisher.congestion_control).endswith("DROP")
            for i in range(100):
                steps.put(example(Step, seq=i))
            status.put(example(ServiceStatus, service="actor"))
            with pytest.raises(TypeError):
                steps.put(example(ServiceStatus))
            got = []
            while len(got) < 101:
                x = inbox.get_message(timeout=5)
                assert x is not None, got
                got.append(x)
            assert [m.seq for _, m in got if isinstance(m, Step)] == list(range(100))
            assert all(r.t_zenoh is not None and abs(r.t_zenoh - r.t_recv) < 5 for r, _ in got)
        finally:
            inbox.close()
            sub.undeclare()
    assert declare_publisher  # exported


# -- separate processes ---------------------------------------------------------------------------------------------


def _spawn(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _readline(proc: subprocess.Popen, timeout: float) -> str:
    out: list[str] = []
    th = threading.Thread(target=lambda: out.append(proc.stdout.readline()), daemon=True)
    th.start()
    th.join(timeout)
    return out[0] if out else ""


@pytest.mark.timeout(90)
def test_router_and_two_client_processes_exchange_step_and_weights():
    port = free_port()
    endpoint = tcp_endpoint(port)
    procs: list[subprocess.Popen] = []
    try:
        router = _spawn("-m", "services", "router", "--port", str(port))
        procs.append(router)
        line = _readline(router, 20)
        assert line.startswith(f"ready {endpoint}"), (line, router.poll())
        sub = _spawn(str(PEER), "sub", endpoint, "live1")
        procs.append(sub)
        assert _readline(sub, 20).strip() == "subscribed"
        pub = _spawn(str(PEER), "pub", endpoint, "live1")
        procs.append(pub)
        pub_out, pub_err = pub.communicate(timeout=30)
        assert pub.returncode == 0, (pub_out, pub_err)
        assert "sent" in pub_out
        sub_out, sub_err = sub.communicate(timeout=30)
        assert sub.returncode == 0, (sub_out, sub_err)
        lines = [json.loads(x) for x in sub_out.splitlines() if x.strip()]
        step, weights, counters = lines
        assert step["key"] == "hitl/live1/step" and step["type"] == "Step"
        assert (step["seq"], step["obs"], step["action"]) == (0, [0.5, -1.0], 3)
        assert step["t_zenoh"] is not None
        assert weights["key"] == "hitl/live1/weights" and weights["version"] == 7
        assert weights["spec"] == {"q.0.weight": [3, 2], "q.0.bias": [3]} and weights["sum"] == 18.0
        assert counters["counters"]["decoded"] == 2
        router.send_signal(signal.SIGTERM)
        router.communicate(timeout=15)
        assert router.returncode == 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=10)
    assert all(p.poll() is not None for p in procs)
    assert not [c for c in psutil.Process().children(recursive=True) if c.pid in {p.pid for p in procs}]


def test_subscription_closes_inbox_before_undeclaring_and_peers_work_without_router():
    port = free_port()
    with open_session(peer_config(listen=[port])) as a, open_session(peer_config(connect=[port])) as b:
        with subscription(b, "hitl/r1/step", maxsize=1, block_timeout=30) as inbox:
            assert inbox.policy == "block"
            steps = MessagePublisher(a, step_key("r1"))
            assert steps.wait_for_subscribers(5)
            for i in range(3):
                steps.put(example(Step, seq=i))
            deadline = time.monotonic() + 5
            while inbox.counters["received"] < 2 and time.monotonic() < deadline:
                time.sleep(0.01)  # the second sample now waits in the callback for room
            t = time.monotonic()
        assert time.monotonic() - t < 5  # leaving did not wait for the 30 s block_timeout
        assert inbox.counters["received"] >= 2
        t = time.monotonic()
    assert time.monotonic() - t < 5  # nor did closing the sessions


def test_a_block_link_outwaits_every_inbox_before_zenoh_closes_it():
    """Zenoh closes a link whose BLOCK message waited `wait_before_close` for room, losing what it queued: every
    session this project opens waits longer than an inbox blocks before it drops and counts."""
    import inspect

    inbox_wait = inspect.signature(Inbox).parameters["block_timeout"].default
    for config in (router_config(7447), client_config(7447), peer_config(listen=[7448])):
        block = json.loads(config.get_json("transport/link/tx/queue/congestion_control/block"))
        assert block["wait_before_close"] / 1e6 >= 2 * inbox_wait


def test_a_listener_tries_another_port_when_the_probed_one_was_taken(monkeypatch):
    """Port 0: the probed port is taken between the probe and the bind (here: taken before) -> another one, and a
    client reaches it there. A port asked for by number that is taken: PortInUse, naming it."""
    import common.wire.transport as transport

    def router_on(port: int):
        return router_config(tcp_endpoint(port))

    with socket.socket() as taken:
        taken.bind((LOOPBACK, 0))
        taken.listen()
        busy = taken.getsockname()[1]
        probes = iter([busy, free_port()])
        monkeypatch.setattr(transport, "free_port", lambda host=LOOPBACK: next(probes))
        session, port = open_listening(router_on, 0)
        try:
            assert port != busy
            with open_session(client_config(tcp_endpoint(port))) as client:
                assert wait_for_router(client)
        finally:
            session.close()
        assert next(probes, None) is None  # (both probes used: the first port was refused)
        with pytest.raises(PortInUse, match=f"port {busy} on {LOOPBACK} is in use"):
            open_listening(router_on, busy)
