"""The same sweep through a real local Ray head (127.0.0.1, two CPUs) gives the local pool's results, and
leaves no Ray process behind."""
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

import psutil
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SWEEP = ["sweep", "--grid", "agent.algo=dqn,dqn-tamer", "--set", "env.episodes=3", "observer.p_feedback=0.3",
         "--trials", "4", "--no-progress", "--boot", "50", "--contrast", "agent.algo=dqn-tamer - agent.algo=dqn"]
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "PYTHONPATH": ROOT}


def free_ports(n):
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def ray_tree(head: psutil.Process, temp: str) -> list[psutil.Process]:
    """The head's descendants and any process naming its private temp dir."""
    try:
        procs = {p.pid: p for p in head.children(recursive=True)}
    except psutil.NoSuchProcess:
        procs = {}
    for p in psutil.process_iter(["cmdline"]):
        if temp in " ".join(p.info["cmdline"] or []):
            procs[p.pid] = p
    return list(procs.values())


@pytest.fixture
def ray_head():
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must fit 107 bytes
    port, dash, agent, metrics = free_ports(4)
    log = open(os.path.join(temp, "start.log"), "w+")
    proc = subprocess.Popen(
        [sys.executable, "-c", "from ray.scripts.scripts import main; main()", "start", "--head", "--block",
         "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2", "--include-dashboard=false",
         f"--dashboard-port={dash}", f"--dashboard-agent-listen-port={agent}", f"--metrics-export-port={metrics}",
         f"--temp-dir={temp}", "--disable-usage-stats"],
        stdout=log, stderr=subprocess.STDOUT, env=ENV, start_new_session=True)
    head = psutil.Process(proc.pid)
    seen: dict[int, psutil.Process] = {}
    try:
        deadline = time.monotonic() + 180
        while "Ray runtime started" not in open(log.name).read():
            assert proc.poll() is None, f"ray start exited: {open(log.name).read()[-2000:]}"
            assert time.monotonic() < deadline, "Ray head did not start in 180 s"
            time.sleep(0.5)
        yield f"127.0.0.1:{port}", lambda: seen.update({p.pid: p for p in ray_tree(head, temp)})
    finally:
        seen.update({p.pid: p for p in ray_tree(head, temp)})
        proc.send_signal(signal.SIGTERM)  # `ray start --block` stops what it started
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        _, alive = psutil.wait_procs(list(seen.values()), timeout=30)
        left = {p.pid: p for p in alive if p.is_running() and p.status() != psutil.STATUS_ZOMBIE}
        left.update({p.pid: p for p in ray_tree(head, temp)})
        left = list(left.values())
        for p in left:  # only what this fixture started, by pid
            p.kill()
        log.close()
        shutil.rmtree(temp, ignore_errors=True)
        assert not left, f"Ray processes left behind: {[(p.pid, p.name()) for p in left]}"


def run(args, timeout=300):
    res = subprocess.run([sys.executable, "-m", "experiments", *args], cwd=ROOT, env=ENV, capture_output=True,
                         text=True, timeout=timeout)
    assert res.returncode == 0, res.stderr[-3000:]
    return res.stdout


def test_a_sweep_through_a_local_ray_head_equals_the_local_pool(tmp_path, ray_head):
    address, snapshot = ray_head
    local = run([*SWEEP, "--out", str(tmp_path / "local"), "--workers", "2"])
    assert "computed on local" in local
    remote = run([*SWEEP, "--out", str(tmp_path / "ray"), "--ray", address])
    snapshot()
    assert "computed on ray" in remote
    for name in ("trials.csv", "summary.csv", "contrasts.json"):
        assert (tmp_path / "ray" / name).read_text() == (tmp_path / "local" / name).read_text(), name
    cached = sorted(p.relative_to(tmp_path / "ray") for p in (tmp_path / "ray" / "cache").rglob("*.json"))
    assert cached == sorted(p.relative_to(tmp_path / "local") for p in (tmp_path / "local" / "cache").rglob("*.json"))
    # the Ray run's results were streamed back into its own cache: a repeat computes nothing
    assert "nothing to compute" in run([*SWEEP, "--out", str(tmp_path / "ray"), "--ray", address])
