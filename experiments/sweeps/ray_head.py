"""A private local Ray head (127.0.0.1, free ports, its own temp dir) that is stopped with everything it
started: for the Ray test and the sweep benchmark. `ray start --block` stops its processes on SIGTERM;
what is still alive afterwards (found by parentage or by the private temp dir, never by name) is killed
by pid and reported."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager

import psutil


def free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def ray_tree(head: psutil.Process, temp: str) -> dict[int, psutil.Process]:
    """The head's descendants and any process naming its private temp dir."""
    try:
        procs = {p.pid: p for p in head.children(recursive=True)}
    except psutil.NoSuchProcess:
        procs = {}
    for p in psutil.process_iter(["cmdline"]):
        try:
            if temp in " ".join(p.info["cmdline"] or []):
                procs[p.pid] = p
        except psutil.Error:
            continue
    return procs


class Head:
    def __init__(self, address: str, head: psutil.Process, temp: str):
        self.address, self.head, self.temp = address, head, temp
        self.seen: dict[int, psutil.Process] = {}
        self.left: list[tuple[int, str]] = []

    def snapshot(self) -> None:
        """Remember the processes the head has now (workers come and go)."""
        self.seen.update(ray_tree(self.head, self.temp))


@contextmanager
def local_head(num_cpus: int = 2, start_timeout: float = 180.0):
    """Yields a `Head`; on exit `head.left` lists (pid, name) of processes that had to be killed."""
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must fit 107 bytes
    port, dash, agent, metrics = free_ports(4)
    log_path = os.path.join(temp, "start.log")
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-c",
                "from ray.scripts.scripts import main; main()",
                "start",
                "--head",
                "--block",
                "--node-ip-address=127.0.0.1",
                f"--port={port}",
                f"--num-cpus={num_cpus}",
                "--include-dashboard=false",
                f"--dashboard-port={dash}",
                f"--dashboard-agent-listen-port={agent}",
                f"--metrics-export-port={metrics}",
                f"--temp-dir={temp}",
                "--disable-usage-stats",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        )
    head = Head(f"127.0.0.1:{port}", psutil.Process(proc.pid), temp)
    try:
        deadline = time.monotonic() + start_timeout
        while "Ray runtime started" not in _read(log_path):
            if proc.poll() is not None:
                raise RuntimeError(f"ray start exited: {_read(log_path)[-1500:]}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the Ray head did not start in {start_timeout:.0f} s")
            time.sleep(0.5)
        yield head
    finally:
        head.snapshot()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the group this function started
            proc.wait(timeout=10)
        _, alive = psutil.wait_procs(list(head.seen.values()), timeout=30)
        left = {p.pid: p for p in alive if p.is_running() and p.status() != psutil.STATUS_ZOMBIE}
        left.update(ray_tree(head.head, temp))
        for p in left.values():
            try:
                head.left.append((p.pid, p.name()))
                p.kill()
            except psutil.Error:
                pass
        shutil.rmtree(temp, ignore_errors=True)


def _read(path: str) -> str:
    try:
        with open(path) as fh:
            return fh.read()
    except OSError:
        return ""
