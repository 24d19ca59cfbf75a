"""The fast engine (msgspec decoders generated from the specs: ``FastDecoder`` in ``common/protocol/_base.py``, its
types derived in ``_fast.py``) against the full check: whatever it accepts, the full check accepts too, with an equal
message; whatever else comes in, ``decode`` answers as the full check does, with the same reason. And a message in its
usual form does take the fast path."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.protocol import Credit, EpisodeSummary, Feedback, Ingest, ProtocolError, RunConfig, Step
from common.protocol._base import encode_json, fast_decoder, parse_json

from .strategies import ANY_JSON, JSON_TYPES, example, messages

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def outcome(fn):
    try:
        return "ok", fn()
    except ProtocolError as e:
        return "rejected", e.reason


def full(cls, data: bytes):
    return outcome(lambda: cls.from_json_obj(parse_json(data, cls.MAX_BYTES)))


def agree(cls, data: bytes) -> None:
    """The fast decoder takes nothing the full check refuses; ``decode`` is the full check's answer either way."""
    expected = full(cls, data)
    fast = fast_decoder(cls).decode(data)
    if fast is not None:
        assert expected == ("ok", fast), data[:300]
    assert outcome(lambda: cls.decode(data)) == expected, data[:300]


def spellings(obj) -> list[bytes]:
    """The same JSON value written three ways: msgspec's (the canonical form), Python's compact, and spaced."""
    out = [encode_json(obj), json.dumps(obj, separators=(",", ":"), ensure_ascii=False).encode()]
    return out + [json.dumps(obj).encode()]


@pytest.mark.parametrize("cls", JSON_TYPES, ids=lambda c: c.__name__)
@SETTINGS
@given(data=st.data())
def test_fast_path_agrees_on_valid_and_mutated_messages(cls, data):
    raw = data.draw(messages(cls)).encode()
    agree(cls, raw)
    obj = parse_json(raw, 1 << 30)
    name = data.draw(st.sampled_from(sorted(obj)))
    obj[name] = data.draw(ANY_JSON)
    for spelled in spellings(obj):
        agree(cls, spelled)
    del obj[name]
    agree(cls, encode_json(obj))


@pytest.mark.parametrize("cls", [Step, Feedback, Credit, Ingest, EpisodeSummary, RunConfig], ids=lambda c: c.__name__)
def test_a_message_in_its_usual_form_takes_the_fast_path(cls):
    msg = example(cls)
    data = msg.encode()
    assert fast_decoder(cls).decode(data) == msg == cls.decode(data)


def test_an_ingest_carrying_credits_takes_the_fast_path_and_checks_each_credit():
    ingest = example(Ingest, credits=[example(Credit), example(Credit, seq=9)])
    data = ingest.encode()
    assert fast_decoder(Ingest).decode(data) == ingest == Ingest.decode(data)
    bad = data.replace(b'"lost_mass":', b'"lost_mass":2.5,"x":', 1)  # an unknown field in a carried Credit
    assert fast_decoder(Ingest).decode(bad) is None
    assert full(Ingest, bad) == ("rejected", "extra_field") == outcome(lambda: Ingest.decode(bad))


def test_what_msgspec_alone_would_accept_goes_to_the_full_check():
    raw = example(Step).encode()
    twice = raw.replace(b'"seq":3,', b'"seq":3,"seq":4,')  # a repeated key: msgspec keeps the last
    assert twice != raw and fast_decoder(Step).decode(twice) is None
    assert full(Step, twice) == ("rejected", "malformed") == outcome(lambda: Step.decode(twice))
    # valid but not canonical: 3.0 for an integer, 2 for a float, spaces; the full check reads them
    for odd in (
        raw.replace(b'"seq":3,', b'"seq":3.0,'),
        raw.replace(b'"reward":', b'"reward": '),
        json.dumps(json.loads(raw)).encode(),
    ):
        assert fast_decoder(Step).decode(odd) is None
        assert Step.decode(odd) == example(Step)
    for bad, reason in [(b"NaN", "non_finite"), (b"1e999", "non_finite"), (b'"x"', "wrong_type")]:
        data = raw.replace(b'"reward":' + raw.split(b'"reward":')[1].split(b",")[0], b'"reward":' + bad)
        assert data != raw and outcome(lambda d=data: Step.decode(d)) == ("rejected", reason)


def test_encode_never_writes_nan_as_null():
    """msgspec writes NaN and infinity as null; a nullable field would then decode as None. Encode refuses them."""
    for value in (math.nan, math.inf):
        with pytest.raises(ProtocolError) as e:
            example(Feedback, t_page=value).encode()
        assert e.value.reason == "non_finite"
    assert example(Feedback, t_page=None).encode() == encode_json(example(Feedback, t_page=None).to_json_obj())


def test_encode_of_a_renamed_field_numpy_values_and_tuples_is_the_full_paths():
    summary = example(EpisodeSummary)
    assert fast_decoder(EpisodeSummary).encode(summary) is None  # `return_` is `return` on the wire
    assert EpisodeSummary.decode(summary.encode()) == summary
    step = example(Step)
    odd = example(Step, obs=tuple(step.obs), reward=np.float64(step.reward), action=np.int64(step.action))
    assert fast_decoder(Step).encode(odd) is None
    assert odd.encode() == step.encode() and Step.decode(odd.encode()) == step
