"""Access control over a live secured router: TLS + user/password + ACL (common/security.py).

One secured router (``python -m services security router``) and one recorder-identity subscriber run as
processes for the whole module; each test starts its publishers as further processes and asserts on what
the recorder actually received. Each test uses its own run name, so its samples are told apart.

A denied put is dropped silently, so "nothing arrived" needs a bound: the forbidden puts are followed, in
the same session, by an allowed sentinel put. One session's puts reach the router over one link in order,
so once the sentinel has arrived, anything sent before it would have arrived too.
"""

from __future__ import annotations

import json
import os
import queue
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from common.security import (
    SecurityConfig,
    SecurityError,
    access_control,
    client_config_for,
    generate_certificates,
    load_security,
    publish_keys,
    read_credentials,
    router_config_dict,
    tls_endpoint,
)
from common.wire.transport import free_port

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]

ROOT = Path(__file__).resolve().parents[2]
CLIENT = Path(__file__).with_name("secure_client.py")
TEACHERS = ("alice", "bob")


def _reader(stream, lines: queue.Queue[str]) -> None:
    for line in stream:
        lines.put(line.rstrip("\n"))
    lines.put(None)


def _first_line(lines: queue.Queue[str | None], timeout: float) -> str | None:
    try:
        return lines.get(timeout=timeout)
    except queue.Empty:
        return None


def _stop(proc: subprocess.Popen, *, close_stdin: bool = False) -> None:
    if close_stdin and proc.stdin:
        proc.stdin.close()
    else:
        proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory) -> Path:
    """``python -m services security init DIR --teachers alice,bob`` (the CLI, as a user runs it)."""
    d = tmp_path_factory.mktemp("security") / "sec"
    out = subprocess.run(
        [sys.executable, "-m", "services", "security", "init", str(d), "--teachers", ",".join(TEACHERS)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return d


@pytest.fixture(scope="module")
def router(deployment: Path):
    port = free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services",
            "security",
            "router",
            "--security",
            str(deployment / "security.json"),
            "--port",
            str(port),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_reader, args=(proc.stdout, lines), daemon=True).start()
    try:
        line = _first_line(lines, 20)
        assert line and line.startswith(f"ready {tls_endpoint(port)} "), line
        yield tls_endpoint(port)
    finally:
        _stop(proc)


class Recorder:
    """The recorder identity's subscriber to ``hitl/**`` in its own process; collects what it prints."""

    def __init__(self, deployment: Path, endpoint: str):
        self.proc = subprocess.Popen(
            [
                sys.executable,
                str(CLIENT),
                "sub",
                "--security",
                str(deployment / "clients" / "recorder" / "security.json"),
                "--endpoint",
                endpoint,
                "--user",
                "recorder",
                "--key",
                "hitl/**",
            ],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        self.samples: list[dict] = []
        self._cond = threading.Condition()
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            line = line.strip()
            if line == "subscribed":
                self._ready.set()
            elif line.startswith("{"):
                with self._cond:
                    self.samples.append(json.loads(line))
                    self._cond.notify_all()

    def of_run(self, run: str) -> list[tuple[str, str]]:
        with self._cond:
            return [(s["key"], s["payload"]) for s in self.samples if s["key"].split("/")[1] == run]

    def wait_for(self, key: str, payload: str, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not any(s["key"] == key and s["payload"] == payload for s in self.samples):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True


@pytest.fixture(scope="module")
def recorder(deployment: Path, router: str):
    rec = Recorder(deployment, router)
    try:
        assert rec._ready.wait(20), "recorder did not subscribe"
        yield rec
    finally:
        _stop(rec.proc, close_stdin=True)


def publish(
    deployment: Path, endpoint: str, user: str, *puts: tuple[str, str], connect_timeout: float = 5.0, **flags: object
) -> dict:
    """Run a publisher process as ``user`` (its own client folder's security.json) and return its report."""
    folder = deployment / "clients" / (user if (deployment / "clients" / user).is_dir() else "learner")
    cmd = [
        sys.executable,
        str(CLIENT),
        "pub",
        "--security",
        str(folder / "security.json"),
        "--endpoint",
        endpoint,
        "--user",
        user,
        "--connect-timeout",
        str(connect_timeout),
    ]
    for key, payload in puts:
        cmd += ["--put", f"{key}={payload}"]
    for flag, value in flags.items():
        cmd += [f"--{flag.replace('_', '-')}"] + ([] if value is True else [str(value)])
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=40)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


# -- allowed -------------------------------------------------------------------------------------------------------


def test_access_learner_weights_and_teacher_feedback_reach_the_recorder(deployment, router, recorder):
    run = "allowed"
    learner = publish(deployment, router, "learner", (f"hitl/{run}/weights", "w1"), (f"hitl/{run}/episode", "e0"))
    alice = publish(deployment, router, "alice", (f"hitl/{run}/feedback/alice", "+1"))
    actor = publish(deployment, router, "actor", (f"hitl/{run}/step", "s0"))
    perception = publish(deployment, router, "perception", (f"hitl/{run}/perception/cam0", "happy"))
    assert all(r["opened"] for r in (learner, alice, actor, perception))
    for key, payload in [
        ("weights", "w1"),
        ("feedback/alice", "+1"),
        ("step", "s0"),
        ("episode", "e0"),
        ("perception/cam0", "happy"),
    ]:
        assert recorder.wait_for(f"hitl/{run}/{key}", payload), (key, recorder.of_run(run))
    assert sorted(recorder.of_run(run)) == sorted(
        [
            (f"hitl/{run}/weights", "w1"),
            (f"hitl/{run}/feedback/alice", "+1"),
            (f"hitl/{run}/step", "s0"),
            (f"hitl/{run}/episode", "e0"),
            (f"hitl/{run}/perception/cam0", "happy"),
        ]
    )


# -- denied puts: silently dropped ----------------------------------------------------------------------------------


def test_access_teacher_cannot_publish_weights(deployment, router, recorder):
    run = "forged-weights"
    report = publish(
        deployment,
        router,
        "alice",
        *[(f"hitl/{run}/weights", f"forged{i}") for i in range(3)],
        (f"hitl/{run}/feedback/alice", "sentinel"),
    )
    assert report["opened"]
    # measured: the denied puts raise nothing and the publisher still sees a matching subscriber
    assert all(p["matching"] and p["result"] == "None" for p in report["puts"])
    assert recorder.wait_for(f"hitl/{run}/feedback/alice", "sentinel")
    assert recorder.of_run(run) == [(f"hitl/{run}/feedback/alice", "sentinel")]


def test_access_teacher_cannot_speak_for_another_teacher(deployment, router, recorder):
    run = "impersonation"
    publish(deployment, router, "alice", (f"hitl/{run}/feedback/bob", "-1"), (f"hitl/{run}/feedback/alice", "+1"))
    publish(deployment, router, "bob", (f"hitl/{run}/feedback/alice", "-1"), (f"hitl/{run}/feedback/bob", "+1"))
    assert recorder.wait_for(f"hitl/{run}/feedback/alice", "+1") and recorder.wait_for(f"hitl/{run}/feedback/bob", "+1")
    assert sorted(recorder.of_run(run)) == [(f"hitl/{run}/feedback/alice", "+1"), (f"hitl/{run}/feedback/bob", "+1")]


def test_access_only_the_learner_publishes_weights_and_only_teachers_feedback(deployment, router, recorder):
    run = "roles"
    publish(
        deployment,
        router,
        "actor",
        (f"hitl/{run}/weights", "x"),
        (f"hitl/{run}/feedback/alice", "x"),
        (f"hitl/{run}/step", "sentinel"),
    )
    publish(
        deployment,
        router,
        "recorder",
        (f"hitl/{run}/weights", "x"),
        (f"hitl/{run}/step", "x"),
        (f"hitl/{run}/status/recorder", "sentinel"),
    )
    publish(
        deployment,
        router,
        "learner",
        (f"hitl/{run}/feedback/alice", "x"),
        (f"hitl/{run}/step", "x"),
        (f"hitl/{run}/other", "x"),
        (f"hitl/{run}/weights", "sentinel"),
    )
    for key in ("step", "status/recorder", "weights"):
        assert recorder.wait_for(f"hitl/{run}/{key}", "sentinel"), key
    assert sorted(recorder.of_run(run)) == sorted(
        [
            (f"hitl/{run}/step", "sentinel"),
            (f"hitl/{run}/status/recorder", "sentinel"),
            (f"hitl/{run}/weights", "sentinel"),
        ]
    )


# -- refused connections -------------------------------------------------------------------------------------------


def _refused(report: dict) -> None:
    assert report == {"opened": False, "error": report.get("error")}
    assert "Unable to connect" in report["error"]


def test_access_without_credentials_is_refused(deployment, router, recorder):
    run = "no-credentials"
    _refused(publish(deployment, router, "learner", (f"hitl/{run}/weights", "x"), no_auth=True, connect_timeout=1))
    publish(deployment, router, "learner", (f"hitl/{run}/weights", "sentinel"))
    assert recorder.wait_for(f"hitl/{run}/weights", "sentinel")
    assert recorder.of_run(run) == [(f"hitl/{run}/weights", "sentinel")]


def test_access_wrong_password_is_refused(deployment, router, recorder):
    run = "wrong-password"
    _refused(
        publish(
            deployment, router, "learner", (f"hitl/{run}/weights", "x"), password="not-the-password", connect_timeout=1
        )
    )
    time.sleep(0.5)
    assert recorder.of_run(run) == []


def test_access_unknown_user_is_refused(deployment, router, recorder):
    _refused(
        publish(deployment, router, "mallory", ("hitl/unknown/weights", "x"), password="whatever", connect_timeout=1)
    )


def test_access_plain_tcp_is_refused(deployment, router, recorder):
    port = int(router.rsplit(":", 1)[1])
    _refused(publish(deployment, router, "learner", ("hitl/tcp/weights", "x"), tcp=port, connect_timeout=1))


def test_access_router_not_signed_by_the_run_ca_is_refused(deployment, router, recorder, tmp_path):
    other = generate_certificates(tmp_path / "other")  # a different CA: as if someone sat in the middle
    _refused(publish(deployment, router, "learner", ("hitl/mitm/weights", "x"), ca=other["ca_cert"], connect_timeout=1))


# -- the files and the rules (no processes) ---------------------------------------------------------------------------


def test_access_init_writes_private_secrets_and_one_folder_per_identity(deployment):
    sec = load_security(deployment / "security.json")
    assert sec.usernames() == ["learner", "actor", "recorder", "perception", "alice", "bob"]
    creds = read_credentials(deployment / "credentials.txt")
    assert sorted(creds) == sorted(sec.usernames()) and len(set(creds.values())) == len(creds)
    for name in ("ca.key", "router.key", "credentials.txt"):
        assert stat.S_IMODE(os.stat(deployment / name).st_mode) == 0o600, name
    for user in sec.usernames():
        folder = deployment / "clients" / user
        assert sorted(p.name for p in folder.iterdir()) == ["ca.pem", "credentials.txt", "security.json"]
        assert read_credentials(folder / "credentials.txt") == {user: creds[user]}
        client = load_security(folder / "security.json")
        assert client.router_key is None and client.password(user) == creds[user]
        assert (folder / "ca.pem").read_bytes() == (deployment / "ca.pem").read_bytes()
    alice = load_security(deployment / "clients" / "alice" / "security.json")
    with pytest.raises(SecurityError):
        alice.password("bob")  # a teacher's machine holds only the teacher's own password


def test_access_rules_are_default_deny_and_least_privilege():
    sec = SecurityConfig(ca_cert="/nonexistent", credentials_file="/nonexistent", teachers=("alice", "bob"))
    acl = access_control(sec)
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert all(r["permission"] == "allow" for r in acl["rules"])
    # writes are ingress puts only; reads (subscribe, receive) cover hitl/** and nothing else
    for rule in acl["rules"]:
        if rule["id"].startswith("publish-"):
            assert rule["messages"] == ["put"] and rule["flows"] == ["ingress"]
        elif rule["id"].startswith("alive-") and rule["id"] not in ("alive-watch", "alive-ask"):
            # liveliness tokens: only ingress, only under the identity's own service name
            assert rule["messages"] == ["liveliness_token"] and rule["flows"] == ["ingress"]
            user = rule["id"][len("alive-") :]
            service = f"teacher.{user}" if user in ("alice", "bob") else user
            assert rule["key_exprs"] == [f"hitl/*/alive/{service}", f"hitl/*/alive/{service}/*"]
        elif rule["id"].startswith("alive-"):
            assert rule["key_exprs"] == ["hitl/*/alive/**"]
            assert "put" not in rule["messages"] and (
                rule["flows"] == ["egress"] or "liveliness_token" not in rule["messages"]
            )
        else:
            assert rule["key_exprs"] == ["hitl/**"]
            assert rule["messages"] == ["declare_subscriber"] or rule["flows"] == ["egress"]

    def own(service):  # each identity only its own status and log (its console's people: <service>-...)
        return [f"hitl/*/{k}/{service}{tail}" for k in ("status", "log") for tail in ("", "-$*")]

    assert publish_keys(sec, "learner") == [
        "hitl/*/weights",
        "hitl/*/snapshot",
        "hitl/*/episode",
        "hitl/*/ingest",
        "hitl/*/credit/*",
    ] + own("learner")
    assert publish_keys(sec, "alice")[:2] == ["hitl/*/feedback/alice", "hitl/*/feedback/alice-$*"]
    assert publish_keys(sec, "alice")[-4:] == own("teacher.alice")
    assert publish_keys(sec, "actor") == ["hitl/*/step", "hitl/*/camera/env"] + own("actor")
    assert publish_keys(sec, "recorder") == own("recorder")
    assert not any(
        "status/*" in k or k.endswith("/status/learner")
        for u in ("actor", "alice", "bob")
        for k in publish_keys(sec, u)
    )
    assert not any(
        "weights" in k for u in ("actor", "recorder", "perception", "alice", "bob") for k in publish_keys(sec, u)
    )
    assert all(s["link_protocols"] == ["tls"] for s in acl["subjects"])
    one_run = access_control(SecurityConfig(ca_cert="x", credentials_file="x", teachers=("alice",), run="r1"))
    assert {k for r in one_run["rules"] for k in r["key_exprs"]} >= {
        "hitl/r1/**",
        "hitl/r1/weights",
        "hitl/r1/feedback/alice",
    }
    with pytest.raises(SecurityError):
        SecurityConfig(ca_cert="x", credentials_file="x", teachers=("learner",))  # identities must differ
    with pytest.raises(SecurityError):
        SecurityConfig(ca_cert="x", credentials_file="x", teachers=("a:b",))  # ':' would break the dictionary


def test_access_client_config_for_refuses_what_it_cannot_secure(deployment):
    sec = load_security(deployment / "clients" / "alice" / "security.json")
    client_config_for(sec, "teacher", 7447, teacher="alice")  # builds
    with pytest.raises(SecurityError):
        client_config_for(sec, "teacher", 7447)  # which teacher?
    with pytest.raises(SecurityError):
        client_config_for(sec, "teacher", "tcp/127.0.0.1:7447", teacher="alice")  # plain tcp
    with pytest.raises(SecurityError):
        client_config_for(sec, "learner", 7447)  # the learner's password is not on alice's machine
    with pytest.raises(SecurityError):
        router_config_dict(sec)  # no router key on a client machine
    full = router_config_dict(load_security(deployment / "security.json"), 7447, host="0.0.0.0")
    assert full["listen"]["endpoints"] == ["tls/0.0.0.0:7447"]
    assert full["transport"]["link"]["protocols"] == ["tls"]
    assert full["access_control"]["default_permission"] == "deny"


def test_access_router_stops_on_sigterm(deployment):
    """The router CLI exits promptly on SIGTERM (a handler that took the stop Event's lock once deadlocked)."""
    for delay in (0.0, 0.07, 0.23):
        port = free_port()
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services",
                "security",
                "router",
                "--security",
                str(deployment / "security.json"),
                "--port",
                str(port),
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        try:
            assert proc.stdout.readline().startswith("ready tls/")
            time.sleep(delay)
            proc.terminate()
            assert proc.wait(5) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
