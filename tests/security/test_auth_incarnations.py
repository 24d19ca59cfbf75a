"""Per-incarnation counters (issue 33): a copy forged with a stolen teacher key, under a new incarnation and a later
signing time, cannot make a receiver drop the real teacher's presses; replays are still refused."""

from __future__ import annotations

import secrets
import time
from unittest import mock

from common.protocol import feedback_key
from common.wire.auth import MAX_INCARNATIONS, Auth, service_credential, teacher_credential

RUN = "inc-test"


def test_a_forged_incarnation_with_a_stolen_teacher_key_drops_no_real_press():
    secret = secrets.token_bytes(32)
    learner = Auth(service_credential(secret, RUN, "learner"))
    stolen = teacher_credential(secret, RUN, "web-1")  # the thief holds the teacher's own credential
    real, thief = Auth(stolen, "real-teacher"), Auth(stolen, "forged-later")
    key = feedback_key(RUN, "web-1")

    def press(auth: Auth, payload: bytes, ahead: float = 0.0) -> tuple[bytes, bytes]:
        with mock.patch("common.wire.auth.time.time", return_value=time.time() + ahead):
            return payload, auth.sign(key, payload)

    first = press(real, b"press-0")
    assert learner.check(key, *first) is None
    forged = press(thief, b"forged", ahead=9.0)  # a new incarnation, signed 9 s in the future (within max_future)
    assert learner.check(key, *forged) is None  # authentic: the key is the teacher's
    for n in range(1, 6):  # the real teacher's presses still in flight: every one is accepted
        assert learner.check(key, *press(real, f"press-{n}".encode())) is None, n
    assert learner.check(key, *first) == "replayed" and learner.check(key, *forged) == "replayed"
    assert learner.rejected == {"replayed_feedback": 2}


def test_many_forged_incarnations_are_forgotten_oldest_first_and_the_real_one_goes_on():
    secret = secrets.token_bytes(32)
    learner = Auth(service_credential(secret, RUN, "learner"))
    stolen = teacher_credential(secret, RUN, "web-1")
    real = Auth(stolen, "real-teacher")
    key = feedback_key(RUN, "web-1")
    assert learner.check(key, b"p0", real.sign(key, b"p0")) is None
    for i in range(3 * MAX_INCARNATIONS):  # a flood of forged incarnations between two real presses
        fake = Auth(stolen, f"forged-{i}")
        assert learner.check(key, b"f", fake.sign(key, b"f")) is None
    kept = learner._last[("teacher.web-1", key)]
    assert len(kept) == MAX_INCARNATIONS and "real-teacher" not in kept
    assert learner.check(key, b"p1", real.sign(key, b"p1")) is None  # counts up in its own incarnation
    assert learner.rejected == {}
