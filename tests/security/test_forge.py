"""Well-formed forgeries against a live run (issue 10): an attacker with its own process-level Zenoh session on
the run's router sends forged weights, `stopped` statuses, sequence and version jumps, a fake incarnation, a
replayed authentic message, and messages signed with a stolen teacher credential. Each changes nothing (the
same actions and returns as the undisturbed run of the same seed) and each is counted by its receivers.

`pytest -k forge` selects them."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from tests.services.live import assert_nothing_left, start_up, wait_for

pytestmark = [pytest.mark.live, pytest.mark.timeout(600)]

# A long history: no feedback is stale however late a busy teacher sends it, so the runs' credited counts agree.
ARGS = ("--algo", "dqn", "--episodes", "6", "--seed", "3", "--max-ahead", "0", "--agent.history-steps", "1000")
ROUNDS = 3  # each forgery is sent this many times


class Attacker:
    """A Zenoh client of the run's router that watches the real traffic and forges on cue."""

    def __init__(self, endpoint: str, run: str, rundir):
        import zenoh

        from common.wire.transport import client_config

        self.run, self.rundir = run, rundir
        self.session = zenoh.open(client_config(endpoint, connect_timeout=20))
        self.statuses: dict[str, object] = {}
        self.weights: list[tuple[bytes, bytes | None]] = []  # real payloads and their attachments
        # what this session sent itself: zenoh also hands a session's own puts to its subscriber, and a forgery taken
        # for the newest real Weights made the "replay" a second bad tag (seen under load)
        self.own_payloads: set[bytes] = set()
        self.steps = 0
        self.last_step = None
        self.feedback = None
        self.feedback_signed_at = 0.0  # the newest signing time seen on a real feedback
        self.sent: dict[str, int] = {}
        self._subs = [self.session.declare_subscriber(f"hitl/{run}/**", self._watch)]

    def _watch(self, sample) -> None:
        from common.protocol import Feedback, ServiceStatus, Step, decode

        key, data = str(sample.key_expr), sample.payload.to_bytes()
        if key.endswith("/weights"):
            if data in self.own_payloads:
                return
            att = sample.attachment
            self.weights.append((data, None if att is None else att.to_bytes()))
            del self.weights[:-4]
            return
        try:
            msg = decode(key, data)
        except Exception:
            return
        if isinstance(msg, ServiceStatus):
            self.statuses[msg.service] = msg
        elif isinstance(msg, Step):
            self.steps += 1
            self.last_step = msg
        elif isinstance(msg, Feedback):
            from common.wire.auth import _parse

            self.feedback = msg
            signed = _parse(None if sample.attachment is None else sample.attachment.to_bytes())
            if signed is not None:
                self.feedback_signed_at = max(self.feedback_signed_at, signed[2])

    def put(self, what: str, key: str, data: bytes, attachment: bytes | None = None, sign=None) -> None:
        """Sends `data` ROUNDS times, with `attachment`, or signed afresh just before each send by `sign`."""
        import zenoh

        self.own_payloads.add(data)
        pub = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        for _ in range(ROUNDS):
            pub.put(data, attachment=attachment if sign is None else sign(key, data))
            time.sleep(0.02)
        pub.undeclare()
        self.sent[what] = self.sent.get(what, 0) + ROUNDS

    def forge_all(self) -> None:
        """Every forgery of the issue, once the real services are running."""
        import dataclasses

        from common.wire.auth import Auth, Credential, make_teacher_credential, load_credential
        from common.protocol import (
            Feedback,
            ServiceStatus,
            Step,
            Weights,
            feedback_key,
            status_key,
            step_key,
            weights_key,
        )

        run = self.run
        real = Weights.decode(self.weights[-1][0])
        learner_inc = real.incarnation
        # 1. a forged Weights message: the real learner's incarnation, version 2^53-1, real-shaped tensors
        top = Weights(
            run=run,
            incarnation=learner_inc,
            version=2**53 - 1,
            t_published=time.time(),
            tensors={k: np.zeros_like(v) for k, v in real.tensors.items()},
        ).encode()
        self.put("weights_unsigned", weights_key(run), top)
        fake_learner = Auth(Credential("learner", run, b"k" * 32))  # a guessed key: a wrong tag
        self.put("weights_bad_tag", weights_key(run), top, fake_learner.sign(weights_key(run), top))
        # a replayed authentic message: real bytes, real tag, already seen
        data, att = self.weights[-1]
        self.put("weights_replayed", weights_key(run), data, att)
        # 2. forged `stopped` statuses of the actor, the learner and the teacher (their real incarnations)
        for service in ("actor", "learner", "teacher.oracle"):
            st = self.statuses[service]
            stopped = dataclasses.replace(
                st, state="stopped", t=time.time(), counters={"steps_published": 1, "feedback_published": 0}
            )
            self.put("status_unsigned", status_key(run, service), stopped.encode())
        # 4. sequence jumps: feedback and a step far ahead of the real ones
        fb = self.feedback
        # the real teacher's own credential, stolen (issue 25): its next feedback at seq +4000, authentic to every
        # receiver. It used to be admitted and move the learner's window: the teacher's real presses that followed
        # were dropped as duplicates. Now it is `bad_seq`, and the real presses are credited as in the calm run.
        # The real teacher presses all the while. Each copy is signed as it leaves, dated just after the newest real
        # press the attacker has seen (its own clock: within the receivers' tolerance): a copy that reaches a receiver
        # after a newer real press is (rightly) a replay there, the others are authentic; and a real press is never
        # older than an accepted copy, so none is taken for a replay (with the copy dated "now", a real press signed
        # just before it but arriving after it was: 2 real presses lost at the recorder in one loaded run).
        import types
        from unittest import mock

        oracle = Auth(load_credential(self.rundir / "credentials" / "teacher.oracle.json"))

        def sign_after_the_newest_press(key: str, data: bytes) -> bytes:
            clock = types.SimpleNamespace(time=lambda: self.feedback_signed_at + 1e-6)
            with mock.patch("common.wire.auth.time", clock):
                return oracle.sign(key, data)

        stolen_jump = dataclasses.replace(fb, seq=fb.seq + 4000, t_reaction=time.time()).encode()
        self.put(
            "stolen_teacher_seq_jump", feedback_key(run, fb.teacher_id), stolen_jump, sign=sign_after_the_newest_press
        )
        jump = dataclasses.replace(fb, seq=fb.seq + 4000, t_reaction=time.time())
        self.put("feedback_seq_jump", feedback_key(run, fb.teacher_id), jump.encode())
        step = self.last_step
        self.put(
            "step_seq_jump",
            step_key(run),
            dataclasses.replace(step, seq=step.seq + 4000, t_action=time.time()).encode(),
        )
        # 5. a fake incarnation announced by a status, then its steps
        fake = dataclasses.replace(
            self.statuses["actor"], incarnation="actor-666-deadbeef", state="ready", t=time.time()
        )
        self.put("fake_incarnation_status", status_key(run, "actor"), fake.encode())
        self.put(
            "fake_incarnation_step",
            step_key(run),
            dataclasses.replace(step, incarnation="actor-666-deadbeef", seq=0, t_action=time.time()).encode(),
        )
        # a stolen teacher credential: it signs as its teacher, never as the learner or the actor
        path = make_teacher_credential(self.rundir / "credentials", run, "mallory", self.rundir / "mallory.json")
        mallory = Auth(load_credential(path))
        stopped = dataclasses.replace(self.statuses["learner"], state="stopped", t=time.time()).encode()
        self.put(
            "teacher_cred_status",
            status_key(run, "learner"),
            stopped,
            mallory.sign(status_key(run, "learner"), stopped),
        )
        self.put("teacher_cred_weights", weights_key(run), top, mallory.sign(weights_key(run), top))
        assert isinstance(fb, Feedback) and isinstance(step, Step) and isinstance(fake, ServiceStatus)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


def run_attacked(tmp_path, run: str) -> tuple:
    launch = start_up(tmp_path, run, *ARGS)  # (its router's port: the launcher's choice, read from the run record)
    run_json = launch.rundir / "config" / "run.json"
    assert wait_for(run_json.exists, 60)
    attacker = Attacker(json.loads(run_json.read_text())["launcher"]["endpoint"], run, launch.rundir)
    done = threading.Event()
    errors: list[BaseException] = []

    def attack() -> None:
        try:
            ok = wait_for(
                lambda: (
                    attacker.steps >= 40
                    and attacker.weights
                    and attacker.feedback is not None
                    and {"actor", "learner", "teacher.oracle"} <= set(attacker.statuses)
                ),
                120,
            )
            assert ok, "the run never got going"
            attacker.forge_all()
        except BaseException as exc:  # reported by the fixture
            errors.append(exc)
        finally:
            done.set()

    threading.Thread(target=attack, daemon=True).start()
    try:
        rc = launch.wait(timeout=400)
    finally:
        done.wait(30)
        attacker.close()
    assert not errors, errors
    return launch, rc, attacker.sent


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("forge")
    calm = start_up(base, "calm", *ARGS)
    assert calm.wait(timeout=400) == 0, calm.out
    attacked, rc, sent = run_attacked(base, "attacked")
    assert rc == 0, attacked.out
    yield calm, attacked, sent
    assert_nothing_left(calm.rundir)
    assert_nothing_left(attacked.rundir)


def actions(rundir) -> list[tuple[int, int, int]]:
    from common.logs.mcap_log import read_log
    from common.protocol import Step

    return [
        (r.message.episode, r.message.t_in_episode, r.message.action)
        for r in read_log(rundir)
        if isinstance(r.message, Step)
    ]


def counters(rundir, service: str) -> dict[str, int]:
    return json.loads((rundir / "stats" / f"{service}.json").read_text())["counters"]


def same_run(calm, attacked) -> None:
    a, b = calm.summary(), attacked.summary()
    assert actions(attacked.rundir) == actions(calm.rundir)
    assert b["returns"] == a["returns"] and len(b["returns"]) == 6
    assert b["steps_learned"] == b["steps_sent"] == a["steps_sent"]
    assert b["feedback_credited"] == a["feedback_credited"] and b["feedback_sent"] == a["feedback_sent"]
    assert b["outcome"] == "ok" and not b["restarts"]


def test_forge_weights_with_the_top_version_change_nothing(runs):
    calm, attacked, sent = runs
    same_run(calm, attacked)
    actor = counters(attacked.rundir, "actor")
    assert actor["auth_unauthenticated_weights"] >= sent["weights_unsigned"]
    assert actor["auth_bad_tag_weights"] >= sent["weights_bad_tag"]
    # a replayed copy is refused as a replay, or as a stale signature once it is re-sent late (a loaded run: all)
    refused = actor.get("auth_replayed_weights", 0) + actor.get("auth_stale_signature_weights", 0)
    assert refused >= sent["weights_replayed"] >= 1
    assert actor["auth_not_permitted_weights"] >= sent["teacher_cred_weights"]


def test_forge_stopped_statuses_end_nothing(runs):
    calm, attacked, sent = runs
    same_run(calm, attacked)
    for service in ("learner", "recorder"):  # both hear every status
        c = counters(attacked.rundir, service)
        assert c["auth_unauthenticated_status"] >= sent["status_unsigned"] + sent["fake_incarnation_status"], c
    teacher = counters(attacked.rundir, "teacher.oracle")  # hears the actor's
    assert teacher["auth_unauthenticated_status"] >= ROUNDS + sent["fake_incarnation_status"]


def test_forge_sequence_jumps_silence_no_real_sender(runs):
    calm, attacked, sent = runs
    same_run(calm, attacked)
    learner = counters(attacked.rundir, "learner")
    assert learner["auth_unauthenticated_feedback"] >= sent["feedback_seq_jump"]
    assert learner["auth_unauthenticated_step"] >= sent["step_seq_jump"] + sent["fake_incarnation_step"]
    assert learner.get("duplicates_feedback", 0) == counters(calm.rundir, "learner").get("duplicates_feedback", 0)
    # the jump signed with the teacher's stolen credential: each copy is refused, as bad_seq where it was authentic,
    # as a replay where the real teacher had signed a press after it (which one depends on the machine's load: a
    # loaded run refused every copy as a replay)
    refused = learner.get("rejected_bad_seq", 0) + learner.get("auth_replayed_feedback", 0)
    assert refused >= sent["stolen_teacher_seq_jump"] >= 1
    s = attacked.summary()  # recorded where authentic (one seq, however many copies), not counted as the teacher's
    assert s["feedback_logged"] == s["feedback_sent"] and s["log"]["not_from_run"].get("feedback", 0) <= 1, s["log"]
    assert "unresolved" not in s["feedback_rejected"], s["feedback_rejected"]


def test_forge_fake_incarnation_retires_no_real_actor(runs):
    calm, attacked, sent = runs
    same_run(calm, attacked)
    s = attacked.summary()
    assert s["actor_incarnations"] == 1
    teacher = counters(attacked.rundir, "teacher.oracle")
    assert teacher["auth_unauthenticated_step"] >= sent["step_seq_jump"] + sent["fake_incarnation_step"]


def test_forge_with_a_stolen_teacher_credential_is_not_permitted(runs):
    calm, attacked, sent = runs
    same_run(calm, attacked)
    for service in ("learner", "recorder"):
        assert counters(attacked.rundir, service)["auth_not_permitted_status"] >= sent["teacher_cred_status"]


def test_forge_stopped_status_in_secured_mode_with_a_teachers_credentials(runs, tmp_path):
    """A stolen teacher password and teacher credential: the router lets it in, as that teacher only; its forged
    `stopped` statuses of the learner and the actor (signed with its own key) never reach a receiver (the access
    rules let an identity publish only its own status), and the run is the undisturbed one."""
    import dataclasses

    import zenoh

    from common.wire.auth import Auth, load_credential, make_teacher_credential
    from common.protocol import status_key
    from common.security import client_config_for, init, load_security

    calm, _, _ = runs
    init(tmp_path / "sec", ["oracle", "alice"], run="secure")
    launch = start_up(tmp_path, "secure", *ARGS, "--security", str(tmp_path / "sec" / "security.json"))
    run_json = launch.rundir / "config" / "run.json"
    assert wait_for(run_json.exists, 60)
    endpoint = json.loads(run_json.read_text())["launcher"]["endpoint"]
    alice = load_security(tmp_path / "sec" / "clients" / "alice" / "security.json")
    stolen = Auth(
        load_credential(
            make_teacher_credential(launch.rundir / "credentials", "secure", "alice", tmp_path / "alice.json")
        )
    )
    seen: dict[str, object] = {}
    sent = 0
    with zenoh.open(client_config_for(alice, "teacher", endpoint, teacher="alice", connect_timeout=20)) as session:
        from common.protocol import ServiceStatus, decode

        def watch(sample):
            try:
                msg = decode(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:
                return
            if isinstance(msg, ServiceStatus):
                seen[msg.service] = msg

        sub = session.declare_subscriber("hitl/secure/status/*", watch)
        assert wait_for(lambda: {"actor", "learner"} <= set(seen), 120)
        for service in ("learner", "actor", "teacher.oracle"):
            key = status_key("secure", service)
            data = dataclasses.replace(
                seen.get(service) or seen["actor"], service=service, state="stopped", t=time.time()
            ).encode()
            pub = session.declare_publisher(key)
            for _ in range(ROUNDS):
                pub.put(data, attachment=stolen.sign(key, data))
                sent += 1
            pub.undeclare()
        sub.undeclare()
    assert launch.wait(timeout=400) == 0, launch.out
    assert_nothing_left(launch.rundir)
    same_run(calm, launch)
    assert sent == 3 * ROUNDS
    for service in ("learner", "recorder"):  # the router dropped them before any receiver saw them
        assert counters(launch.rundir, service).get("auth_not_permitted_status", 0) == 0
