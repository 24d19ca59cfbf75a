"""The decoders' quick path (``Spec.quick``, ``Message.quick_from_json_obj``) against the full check: whatever the
quick path accepts, the full check accepts too, with an equal message; what it leaves, the full check decides."""

from __future__ import annotations

import json
import math
from unittest import mock

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.protocol import ProtocolError, Step
from common.protocol._base import parse_json
from common.protocol._spec import Float, Int, QuickMiss, Str

from .strategies import ANY_JSON, JSON_TYPES, example, messages

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def full(cls, obj):
    """The full check alone (the quick path always misses)."""

    def miss(obj):
        raise QuickMiss

    with mock.patch.object(cls, "quick_from_json_obj", miss):
        return cls.from_json_obj(obj)


def agree(cls, obj) -> None:
    try:
        quick = cls.quick_from_json_obj(obj)
    except QuickMiss:
        return
    assert full(cls, obj) == quick, obj


@pytest.mark.parametrize("cls", JSON_TYPES, ids=lambda c: c.__name__)
@SETTINGS
@given(data=st.data())
def test_quick_agrees_on_valid_and_mutated_messages(cls, data):
    obj = parse_json(data.draw(messages(cls)).encode(), 1 << 30)
    agree(cls, obj)
    name = data.draw(st.sampled_from(sorted(obj)))
    obj[name] = data.draw(ANY_JSON)
    agree(cls, obj)


def test_quick_takes_ordinary_steps_and_leaves_the_odd_ones_to_the_full_check():
    obj = example(Step).to_json_obj()
    assert Step.quick_from_json_obj(obj) == Step.from_json_obj(obj)  # an ordinary step: no miss
    # valid, but not plainly: 1.0 for an integer, an integer for a float, non-ASCII text in a map key
    for field, value in [("seq", 3.0), ("reward", 2), ("info", {"é": 1.0})]:
        odd = {**obj, field: value}
        with pytest.raises(QuickMiss):
            Step.quick_from_json_obj(odd)
        assert Step.from_json_obj(odd) == full(Step, odd)
    # invalid: the full check names the reason
    for field, value, reason in [("reward", math.nan, "non_finite"), ("action", 1024, "bad_value")]:
        with pytest.raises(ProtocolError) as e:
            Step.from_json_obj({**obj, field: value})
        assert e.value.reason == reason


@pytest.mark.parametrize(
    "spec, value",
    [
        (Float(), math.inf),
        (Float(), -math.inf),
        (Float(0.0, 1.0), math.nan),
        (Float(0.0), math.inf),
        (Int(0), True),
        (Int(0), -1),
        (Str(4), "abcde"),
        (Str(8, pattern=r"^[a-z]+$"), "abc\n"),
        (Str(8), "\ud800"),
    ],
)
def test_quick_misses_what_the_full_check_rejects(spec, value):
    with pytest.raises(QuickMiss):
        spec.quick(value)
    with pytest.raises(ProtocolError):
        spec.check(value, "x")


def test_wire_bytes_unchanged():
    msg = example(Step)
    assert json.loads(msg.encode()) == msg.to_json_obj()


def test_each_miss_is_a_new_exception():
    """A shared instance would keep the frames of every raise in its traceback, for the life of the process."""
    caught = []
    for _ in range(2):
        try:
            Int(0).quick(-1)
        except QuickMiss as e:
            caught.append(e)
    assert caught[0] is not caught[1]
