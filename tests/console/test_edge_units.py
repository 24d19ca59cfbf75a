"""The console's edge without a browser (issue 25; the door's checks: test_door_units.py): the page gate's
bounds (names, a 400-digit number, controls), and the press ledger across a console restart."""

from __future__ import annotations

import json

import pytest

from services.console.people import Ledger, PageError, PageGate, Person, RateLimit
from services.console.service import check_name, check_page_id

NOW = 1_800_000_000.0
TOKEN = "t" * 32


def test_the_page_gate_bounds_names_numbers_and_controls():
    gate = PageGate(5.0, 1000, clock=lambda: NOW)
    person = Person("web-1", RateLimit(8, 16), RateLimit(15), controls=RateLimit(2.0, 5.0))
    for name in ("имя", "a b", "../x", "-x", "x" * 33, "ali\u0441e"):
        with pytest.raises(PageError) as e:
            check_name(name)
        assert e.value.reason == "bad_name"
    assert check_name("alice.b-2") == "alice.b-2" and check_name("") is None
    with pytest.raises(PageError):
        check_page_id("short")
    huge = '{"type": "feedback", "value": 1, "t_page": 1' + "0" * 400 + ', "offset": 0, "rtt": 0, "press": 3}'
    with pytest.raises(PageError) as e:
        gate.text(huge, person)
    assert e.value.reason == "bad_value" and e.value.kind == "feedback" and e.value.press == 3
    with pytest.raises(PageError):
        gate.text('{"type": "ping", "t0": 1' + "0" * 400 + "}", person)
    passed = 0
    for _ in range(200):
        try:
            gate.text(json.dumps({"type": "control", "command": "pace", "rate": 4}), person)
            passed += 1
        except PageError as refused:
            assert refused.reason == "control_flood"
    assert passed == 5  # the burst; then 2 per second
    old = {"type": "feedback", "value": 1, "t_page": NOW - 60, "offset": 0, "rtt": 0, "press": 1}
    with pytest.raises(PageError):
        gate.text(json.dumps(old), person)  # a minute old: absurd for a new press ...
    assert gate.text(json.dumps({**old, "resend": True}), person)["resend"]  # ... not for a re-sent one


def test_the_ledger_never_reuses_a_seq_and_recognises_a_resent_press(tmp_path):
    path = str(tmp_path / "ledger.json")
    ledger = Ledger(path)
    ledger.bind("page-aaaaaaaa", "web-alice")
    assert [ledger.seq_for("web-alice", "page-aaaaaaaa", n) for n in range(3)] == [(0, False), (1, False), (2, False)]
    ledger.saved_at -= 2.0  # a second later: a refusal is saved too (at most once a second)
    ledger.dropped("web-alice", "flood")
    restarted = Ledger(path)  # a console SIGKILLed and started again
    assert restarted.page_teacher("page-aaaaaaaa") == "web-alice"
    assert restarted.seq_for("web-alice", "page-aaaaaaaa", 1) == (1, True)  # re-sent: its own seq again
    restarted.bind("page-bbbbbbbb", "web-alice")  # alice comes back in a new tab
    assert restarted.seq_for("web-alice", "page-bbbbbbbb", 0) == (3, False)
    assert restarted.seq_for("web-alice", None, None) == (4, False)
    assert restarted.counters("web-alice") == {
        "feedback_published": 5,
        "presses_received": 6,
        "presses_resent": 1,
        "presses_dropped_flood": 1,
    }
