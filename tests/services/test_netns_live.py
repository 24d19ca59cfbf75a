"""The process graph across machines: the router, recorder, learner, teacher and actor each in its own network
namespace (its own interfaces, addresses and loopback, as separate machines on one LAN), joined by veth pairs
to a bridge, run compose.yaml's commands with --security (TLS, passwords, access rules): a short taught run in
which nothing is lost, while a process in a namespace without credentials gets nothing.

Needs root (`ip netns`; CI runs as root): without it the test fails, it never skips. Addresses are in
198.18.0.0/15 (RFC 2544's benchmark range) and exist only inside the namespaces the test makes; the namespaces
(and with them the veths and the bridge) and every process in them are removed even when the test fails."""

from __future__ import annotations

import json
import os
import random
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.launcher.compose import ROUTER, RUN, compose_graph
from services.launcher.config import UpConfig

pytestmark = [pytest.mark.live, pytest.mark.timeout(420)]

ROOT = Path(__file__).resolve().parents[2]
MACHINES = ("router", "recorder", "learner", "teacher.oracle", "actor", "outsider")
IDENTITY = {"recorder": "recorder", "learner": "learner", "teacher.oracle": "oracle", "actor": "actor"}
STEPS = 240
PORT = 7447  # each machine has its own ports: no clash with anything else on this host


def sh(*argv: str) -> None:
    subprocess.run(argv, check=True, capture_output=True, timeout=30)


class Lan:
    """Namespaces named hitl-<tag>-<i>, one per machine, and a hub namespace holding the bridge."""

    def __init__(self) -> None:
        self.tag = secrets.token_hex(3)
        self.net = f"198.18.{random.randint(1, 254)}"
        self.ns = {m: f"hitl-{self.tag}-{i}" for i, m in enumerate(MACHINES)}
        self.ip = {m: f"{self.net}.{i + 1}" for i, m in enumerate(MACHINES)}
        self.hub = f"hitl-{self.tag}-hub"

    def up(self) -> None:
        sh("ip", "netns", "add", self.hub)
        sh("ip", "-n", self.hub, "link", "add", "br0", "type", "bridge")
        sh("ip", "-n", self.hub, "link", "set", "br0", "up")
        for i, machine in enumerate(MACHINES):
            ns, near, far = self.ns[machine], f"v{self.tag}{i}a", f"v{self.tag}{i}b"
            sh("ip", "netns", "add", ns)
            sh("ip", "link", "add", near, "type", "veth", "peer", "name", far)
            sh("ip", "link", "set", near, "netns", ns)
            sh("ip", "link", "set", far, "netns", self.hub)
            sh("ip", "-n", ns, "link", "set", near, "name", "eth0")
            sh("ip", "-n", ns, "addr", "add", f"{self.ip[machine]}/24", "dev", "eth0")
            sh("ip", "-n", ns, "link", "set", "eth0", "up")
            sh("ip", "-n", ns, "link", "set", "lo", "up")
            sh("ip", "-n", self.hub, "link", "set", far, "master", "br0")
            sh("ip", "-n", self.hub, "link", "set", far, "up")

    def down(self) -> None:
        """Kill what runs in each namespace (only processes this test started live there), then delete it."""
        for ns in [*self.ns.values(), self.hub]:
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except ProcessLookupError:
                    pass
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)

    def start(self, machine: str, argv: list[str], log: Path) -> subprocess.Popen:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
        with open(log, "w") as out:
            return subprocess.Popen(
                ["ip", "netns", "exec", self.ns[machine], sys.executable, *argv],
                cwd=ROOT,
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
            )


@pytest.fixture
def lan():
    assert os.geteuid() == 0, "this test needs root for ip netns (CI runs as root)"
    net = Lan()
    try:
        net.up()
        yield net
    finally:
        net.down()
        left = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert f"hitl-{net.tag}" not in left


def machine_argv(lan: Lan, tmp: Path, run: str, name: str, module: str, argv: list[str]) -> list[str]:
    """compose.yaml's command for one service, with this LAN's router and this test's folders."""
    swap = {
        ROUTER: f"tls/{lan.ip['router']}:{PORT}",
        f"/app/runs/{RUN}": str(tmp / run),
        "/app/credentials/": f"{tmp / 'credentials'}/",
        RUN: run,
    }
    out = []
    for word in argv:
        for old, new in swap.items():
            word = word.replace(old, new)
        out.append(word)
    security = tmp / "sec" / "clients" / IDENTITY[name] / "security.json"
    return ["-m", *module.split(), *out, "--security", str(security)]


OUTSIDER = """
import json, sys, time, zenoh
got, refused = 0, []
def count(sample):
    global got
    got += 1
for name, extra in (("tcp", {}), ("tls-without-password", {"transport/link/tls/root_ca_certificate": sys.argv[3]})):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"{name[:3]}/{sys.argv[1]}:{sys.argv[2]}"]))
    conf.insert_json5("connect/timeout_ms", "3000")
    conf.insert_json5("scouting/multicast/enabled", "false")
    for key, value in extra.items():
        conf.insert_json5(key, json.dumps(value))
    try:
        session = zenoh.open(conf)
    except Exception as exc:
        refused.append(name)
        continue
    sub = session.declare_subscriber("hitl/**", count)
    time.sleep(float(sys.argv[4]))
    session.close()
print(json.dumps({"received": got, "refused": refused}))
"""


INSIDER = """
import sys, time, zenoh
from common.security import client_config_for, load_security
got = 0
def count(sample):
    global got
    got += 1
session = zenoh.open(client_config_for(load_security(sys.argv[1]), "recorder", sys.argv[2]))
sub = session.declare_subscriber(sys.argv[3], count)
time.sleep(float(sys.argv[4]))
session.close()
print(got)
"""


def listen(lan: Lan, tmp: Path, run: str, seconds: float) -> tuple[subprocess.Popen, subprocess.Popen]:
    """On the outsider's machine: a process with no credentials (plain TCP, then TLS with the CA but no
    password) and, as the control, one with the recorder's, both listening while the run goes on."""
    router, ns = lan.ip["router"], lan.ns["outsider"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    outsider = subprocess.Popen(
        [
            "ip",
            "netns",
            "exec",
            ns,
            sys.executable,
            "-c",
            OUTSIDER,
            router,
            str(PORT),
            str(tmp / "sec" / "ca.pem"),
            str(seconds),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env=env,
    )
    insider = subprocess.Popen(
        [
            "ip",
            "netns",
            "exec",
            ns,
            sys.executable,
            "-c",
            INSIDER,
            str(tmp / "sec" / "clients" / "recorder" / "security.json"),
            f"tls/{router}:{PORT}",
            f"hitl/{run}/**",
            str(seconds),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env=env,
    )
    return outsider, insider


def wait_ready(log: Path, proc: subprocess.Popen, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while "ready" not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.2)


def start_run(lan: Lan, tmp: Path, run: str) -> dict[str, subprocess.Popen]:
    """The secured router, then compose.yaml's services in the launcher's order, each on its own machine."""
    from common.security import init

    init(tmp / "sec", ["oracle"], router_host=lan.ip["router"], port=PORT, run=run)
    sh(sys.executable, "-m", "services", "credentials", "--run", run, "--out", str(tmp / "credentials"))
    (tmp / run / "logs").mkdir(parents=True)
    logs = tmp / run / "logs"
    procs = {
        "router": lan.start(
            "router",
            [
                "-m",
                "services",
                "security",
                "router",
                "--security",
                str(tmp / "sec" / "security.json"),
                "--host",
                "0.0.0.0",
            ],
            logs / "router.log",
        )
    }
    wait_ready(logs / "router.log", procs["router"], 60)
    for name, module, argv in compose_graph(UpConfig.flat(max_steps=STEPS, episodes=1000, seed=2)):
        procs[name] = lan.start(name, machine_argv(lan, tmp, run, name, module, argv), logs / f"{name}.log")
    return procs


def summary(tmp: Path, run: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "services.replay", "summary", str(tmp / run / "session.mcap"), "--json", "--no-plot"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_a_taught_run_across_five_machines_with_security_and_an_outsider_who_gets_nothing(lan, tmp_path):
    run = f"lan{lan.tag}"
    procs = start_run(lan, tmp_path, run)
    try:
        outsider, insider = listen(lan, tmp_path, run, 4.0)
        procs.update(outsider=outsider, insider=insider)
        seen, control = outsider.communicate(timeout=90), insider.communicate(timeout=90)
        for name in ("actor", "teacher.oracle", "learner", "recorder"):
            assert procs[name].wait(timeout=300) == 0, (tmp_path / run / "logs" / f"{name}.log").read_text()[-3000:]
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    assert int(control[0].split()[-1]) > 0, control  # the same machine with credentials hears the run
    seen = json.loads(seen[0].strip().splitlines()[-1])
    assert seen == {"received": 0, "refused": ["tcp", "tls-without-password"]}, seen
    s = summary(tmp_path, run)
    assert s["steps_sent"] == STEPS == s["steps_logged"] == s["steps_learned"], s
    assert s["feedback_sent"] > 0 and s["feedback_logged"] == s["feedback_sent"], s
    assert s["feedback_credited"] + sum(s["feedback_rejected"].values()) == s["feedback_logged"], s
    refused = {(who, why): k for who, reasons in s["rejected_inputs"].items() for why, k in reasons.items()}
    assert set(why for _, why in refused) <= {"unknown_incarnation"} and sum(refused.values()) <= 1, refused
