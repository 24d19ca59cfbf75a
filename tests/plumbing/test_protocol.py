"""Protocol: round trips, schema agreement, and every decoder's rejection of bad input."""

from __future__ import annotations

import dataclasses
import json
import struct
from unittest import mock

import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.protocol import (
    KEYS,
    MESSAGE_TYPES,
    REASONS,
    EpisodeSummary,
    Feedback,
    ProtocolError,
    RunConfig,
    ServiceStatus,
    Step,
    Weights,
    camera_key,
    config_key,
    decode,
    episode_key,
    feedback_key,
    feedback_wildcard,
    ingest_key,
    message_type,
    parse_key,
    perception_key,
    run_prefix,
    status_key,
    step_key,
    validate_name,
    weights_key,
    shown_key,
    control_key,
    credit_key,
)
from common.protocol import Log, ObserverReaction
from common.protocol._weights import header_json

from .strategies import ALL_TYPES, ANY_JSON, JSON_TYPES, example, messages

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def validator(cls):
    schema = cls.json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def reason_of(fn, *args, **kwargs) -> str:
    with pytest.raises(ProtocolError) as info:
        fn(*args, **kwargs)
    assert info.value.reason in REASONS
    return info.value.reason


def raw(cls, **changes) -> bytes:
    """Encode an example with fields changed on the wire, bypassing encode()'s validation."""
    obj = example(cls).to_json_obj()
    for k, v in changes.items():
        if v is DROP:
            del obj[k]
        else:
            obj[k] = v
    return json.dumps(obj).encode()


DROP = object()


# -- round trips ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", JSON_TYPES, ids=lambda c: c.__name__)
def test_schema_is_valid_draft_2020_12(cls):
    validator(cls)


@pytest.mark.parametrize("cls", JSON_TYPES, ids=lambda c: c.__name__)
@SETTINGS
@given(data=st.data())
def test_round_trip_and_schema_accepts(cls, data):
    msg = data.draw(messages(cls))
    wire = msg.encode()
    assert isinstance(wire, bytes)
    back = cls.decode(wire)
    assert back == msg
    assert back.encode() == wire
    validator(cls).validate(json.loads(wire))


@SETTINGS
@given(msg=messages(Weights))
def test_weights_round_trip(msg):
    back = Weights.decode(msg.encode(), expected=msg.spec())
    assert back.same_as(msg)
    for a in back.tensors.values():
        assert a.dtype == np.float32
    validator(Weights).validate(header_json(msg.encode()))


def test_examples_round_trip_by_key():
    keys = {
        Step: step_key("r1"),
        Feedback: feedback_key("r1", "oracle"),
        Weights: weights_key("r1"),
        ServiceStatus: status_key("r1", "learner"),
        RunConfig: config_key("r1"),
    }
    for cls in ALL_TYPES:
        key = (
            keys.get(cls)
            or {
                "EpisodeSummary": episode_key("r1"),
                "CompressedImage": camera_key("r1", "cam0"),
                "ExpressionPrediction": perception_key("r1", "cam0"),
                "Ingest": ingest_key("r1"),
                "Shown": shown_key("r1", "alice"),
                "Control": control_key("r1"),
                "Credit": credit_key("r1", "alice"),
                "WeightsSnapshot": "hitl/r1/snapshot",
                "Request": "hitl/r1/request",
            }[cls.__name__]
        )
        msg = example(cls)
        back = decode(key, msg.encode())
        assert type(back) is cls
        assert back.same_as(msg) if cls is Weights else back == msg
        assert message_type(key) is cls


def test_numpy_values_encode_as_plain_json():
    msg = example(
        Step,
        obs=np.array([0.5, 1.0], np.float32),
        next_obs=(np.float64(1.0), np.float32(2.0)),
        action=np.int64(3),
        seq=np.uint32(9),
        terminated=np.bool_(True),
    )
    back = Step.decode(msg.encode())
    assert back.obs == [0.5, 1.0] and back.next_obs == [1.0, 2.0] and back.action == 3 and back.terminated is True


def test_optional_diagnostics_may_be_absent_or_null():
    assert Feedback.decode(raw(Feedback, ref_seq=DROP, intended=DROP)).ref_seq is None
    assert Feedback.decode(raw(Feedback, ref_seq=None, intended=None)).intended is None
    assert example(Feedback, ref_seq=None, intended=None).encode()


def test_episode_summary_return_field_is_named_return_on_the_wire():
    assert '"return":0.9' in example(EpisodeSummary).encode().decode()


# -- rejections with the right reason ---------------------------------------------------------------------------


@pytest.mark.parametrize("cls", ALL_TYPES, ids=lambda c: c.__name__)
def test_malformed_and_oversized(cls):
    assert reason_of(cls.decode, b"{not json") == "malformed"
    assert reason_of(cls.decode, b"\xff\xfe\x00") == "malformed"
    assert reason_of(cls.decode, b"x" * (cls.MAX_BYTES + 1)) == "oversized"
    assert reason_of(cls.decode, "a str, not bytes") == "malformed"


@pytest.mark.parametrize("cls", JSON_TYPES, ids=lambda c: c.__name__)
def test_json_rejections(cls):
    first = cls.wire_fields()[0].wire
    assert reason_of(cls.decode, b"[]") == "wrong_type"
    assert reason_of(cls.decode, raw(cls, **{first: DROP})) == "missing_field"
    assert reason_of(cls.decode, raw(cls, surplus=1)) == "extra_field"
    assert reason_of(cls.decode, raw(cls, **{first: [1]})) == "wrong_type"
    good = example(cls).encode()
    assert reason_of(cls.decode, b'{"a":1,"a":2}') == "malformed"
    assert reason_of(cls.decode, good[:-1] + b',"x":NaN}') == "non_finite"
    assert reason_of(cls.decode, b"\xef\xbb\xbf" + good) == "malformed"  # a BOM is not JSON


def test_step_rejections():
    assert reason_of(Step.decode, raw(Step, reward=float("nan"))) == "non_finite"  # json.dumps writes NaN
    assert reason_of(Step.decode, raw(Step).replace(b'"reward": -0.01', b'"reward": 1e999')) == "non_finite"
    assert reason_of(Step.decode, raw(Step, obs=[0.0, float("inf")])) == "non_finite"
    assert reason_of(Step.decode, raw(Step, seq=-1)) == "bad_value"
    assert reason_of(Step.decode, raw(Step, seq=2**53)) == "bad_value"
    assert reason_of(Step.decode, raw(Step, action=True)) == "wrong_type"
    assert reason_of(Step.decode, raw(Step, action=1.5)) == "wrong_type"
    assert Step.decode(raw(Step, action=2.0)).action == 2  # JSON Schema's integer admits 2.0
    assert reason_of(Step.decode, raw(Step, terminated=0)) == "wrong_type"
    assert reason_of(Step.decode, raw(Step, obs=[])) == "bad_value"
    assert reason_of(Step.decode, raw(Step, obs=["1"])) == "wrong_type"
    assert reason_of(Step.decode, raw(Step, next_obs=[1.0])) == "bad_shape"
    assert reason_of(Step.decode, raw(Step, info={"k": "v"})) == "wrong_type"
    assert reason_of(Step.decode, raw(Step, info={f"k{i}": 1.0 for i in range(17)})) == "bad_value"
    assert reason_of(Step.decode, raw(Step, t_action=-1.0)) == "bad_value"
    assert reason_of(Step.decode, raw(Step, run="a/b")) == "bad_value"
    assert reason_of(Step.decode, raw(Step, run="x\n")) == "bad_value"
    assert reason_of(Step.decode, raw(Step).replace(b'"run": "r1"', b'"run": "\\ud800"')) == "bad_value"
    # more digits than Python's int() accepts from a string
    assert reason_of(Step.decode, raw(Step).replace(b'"seq": 3', b'"seq": ' + b"9" * 5000)) == "malformed"
    assert reason_of(Step.decode, b"[" * 5000 + b"]" * 5000) == "malformed"


def test_encode_validates_too():
    assert reason_of(example(Step, reward=float("nan")).encode) == "non_finite"
    assert reason_of(example(Step, obs=[1.0], next_obs=[1.0, 2.0]).encode) == "bad_shape"
    assert reason_of(example(Feedback, value=0).encode) == "bad_value"
    big = {f"{i:064d}": 2**53 - 1 for i in range(256)}  # each field in range, the whole too large
    assert reason_of(example(ServiceStatus, counters=big).encode) == "oversized"
    # The largest valid Step still fits its limit.
    assert (
        len(
            example(
                Step,
                obs=[-1.2345678901234567e-300] * 1024,
                next_obs=[-1.2345678901234567e-300] * 1024,
                info={f"{i:064d}": -1.2345678901234567e-300 for i in range(16)},
            ).encode()
        )
        <= Step.MAX_BYTES
    )


def test_feedback_rejections():
    for v in (0, 2, -2, "1"):
        assert reason_of(Feedback.decode, raw(Feedback, value=v)) in ("bad_value", "wrong_type")
    assert reason_of(Feedback.decode, raw(Feedback, intended=0)) == "bad_value"
    assert reason_of(Feedback.decode, raw(Feedback, ref_seq=-1)) == "bad_value"
    assert reason_of(Feedback.decode, raw(Feedback, source="")) == "bad_value"


def test_other_rejections():
    assert reason_of(ServiceStatus.decode, raw(ServiceStatus, state="sleeping")) == "bad_value"
    assert reason_of(ServiceStatus.decode, raw(ServiceStatus, counters={"x": -1})) == "bad_value"
    from common.protocol import CompressedImage, ExpressionPrediction

    assert reason_of(CompressedImage.decode, raw(CompressedImage, data="not base64!")) == "bad_value"
    assert reason_of(CompressedImage.decode, raw(CompressedImage, timestamp={"sec": 1})) == "missing_field"
    assert reason_of(CompressedImage.decode, raw(CompressedImage, timestamp={"sec": 1, "nsec": 10**9})) == "bad_value"
    assert ExpressionPrediction.decode(raw(ExpressionPrediction, box=None)).box is None
    assert reason_of(ExpressionPrediction.decode, raw(ExpressionPrediction, confidence=1.5)) == "bad_value"
    assert reason_of(RunConfig.decode, raw(RunConfig, protocol=2)) == "bad_value"
    assert reason_of(RunConfig.decode, raw(RunConfig, config=[1])) == "wrong_type"
    deep: object = 1
    for _ in range(40):
        deep = [deep]
    assert reason_of(RunConfig.decode, raw(RunConfig, config={"d": deep})) == "bad_value"


# -- arbitrary input: only ProtocolError, and agreement with the JSON Schema ----------------------------------

DECODERS = [(cls.__name__, cls.decode) for cls in ALL_TYPES] + [
    (f"decode[{spec.kind}]", (lambda key: lambda b: decode(key, b))(spec.key("r1", "x" if spec.param else None)))
    for spec in KEYS.values()
]


@pytest.mark.parametrize("name,fn", DECODERS, ids=[n for n, _ in DECODERS])
@SETTINGS
@given(data=st.binary(max_size=300))
def test_arbitrary_bytes_raise_only_protocol_error(name, fn, data):
    try:
        fn(data)
    except ProtocolError as e:
        assert e.reason in REASONS


@SETTINGS
@given(data=st.binary(max_size=300), header=ANY_JSON)
def test_weights_arbitrary_headers_raise_only_protocol_error(data, header):
    blob = json.dumps(header).encode()
    for payload in (struct.pack("<Q", len(blob)) + blob + data, data):
        try:
            Weights.decode(payload)
        except ProtocolError as e:
            assert e.reason in REASONS


#: every JSON message type: valid under its schema if and only if the decoder accepts it (its CROSS_RULES aside)
SCHEMA_TYPES = JSON_TYPES + (Log, ObserverReaction)


def test_every_json_message_type_has_the_schema_property_tests():
    assert {c for c in MESSAGE_TYPES if c.MESSAGE_ENCODING == "json"} <= set(SCHEMA_TYPES)


@pytest.mark.parametrize("cls", SCHEMA_TYPES, ids=lambda c: c.__name__)
@SETTINGS
@given(value=ANY_JSON)
def test_arbitrary_json_agrees_with_schema(cls, value):
    check(cls, value)


@pytest.mark.parametrize("cls", SCHEMA_TYPES, ids=lambda c: c.__name__)
@SETTINGS
@given(data=st.data())
def test_mutated_messages_agree_with_schema(cls, data):
    """Valid messages with one field replaced by arbitrary JSON, dropped, or an extra one added."""
    obj = data.draw(messages(cls)).to_json_obj()
    names = sorted(obj)
    what = data.draw(st.sampled_from(["replace", "drop", "add"]))
    if what == "replace":
        obj[data.draw(st.sampled_from(names))] = data.draw(ANY_JSON)
    elif what == "drop":
        del obj[data.draw(st.sampled_from(names))]
    else:
        obj[data.draw(st.text(max_size=8))] = data.draw(ANY_JSON)
    check(cls, obj)


def check(cls, value):
    wire = json.dumps(value).encode()
    try:
        cls.decode(wire)
        accepted = True
    except ProtocolError as e:
        assert e.reason in REASONS
        accepted = False
    if len(wire) > cls.MAX_BYTES:
        return
    schema_ok = validator(cls).is_valid(json.loads(wire))
    # The decoder is at least as strict as the schema; it is stricter only through the documented
    # cross-field rules (CROSS_RULES, e.g. Step: len(next_obs) == len(obs)): without them it accepts.
    if accepted:
        assert schema_ok, value
    if schema_ok and not accepted:
        assert cls.CROSS_RULES, value
        with mock.patch.object(cls, "_cross_check", lambda self: None):
            cls.decode(wire)


@settings(max_examples=300, deadline=None)
@given(version=st.one_of(st.integers(0, 2**60), st.text("0123456789", min_size=1, max_size=18)))
def test_weights_header_schema_and_decoder_agree_on_the_version(version):
    """The safetensors header's version: valid under the schema if and only if the decoder accepts it."""
    data = example(Weights).encode()
    header = header_json(data)
    header["__metadata__"]["version"] = str(version)
    body = json.dumps(header).encode()
    (n,) = struct.unpack("<Q", data[:8])
    wire = struct.pack("<Q", len(body)) + body + data[8 + n :]
    try:
        Weights.decode(wire)
        accepted = True
    except ProtocolError:
        accepted = False
    assert validator(Weights).is_valid(header) == accepted, version


# -- weights ---------------------------------------------------------------------------------------------------


def test_weights_shape_and_name_mismatch():
    w = example(Weights)
    data = w.encode()
    assert Weights.decode(data, expected={"q.0.weight": (4, 2), "q.0.bias": (4,)}).version == 5
    assert reason_of(Weights.decode, data, expected={"q.0.weight": (2, 4), "q.0.bias": (4,)}) == "bad_shape"
    assert reason_of(Weights.decode, data, expected={"q.0.weight": (4, 2)}) == "bad_shape"
    assert reason_of(Weights.decode, data, expected={"q.0.weight": (4, 2), "q.0.bias": (4,), "h": (1,)}) == "bad_shape"


def test_weights_revision_is_optional_and_orders_publications():
    """Older logs' Weights have no revision (decoded as None); among weights of one version the revision orders
    them: the same steps learned plus a press's H update is newer."""
    import safetensors.numpy

    w = example(Weights)
    meta = {k: v for k, v in w._metadata().items() if k != "revision"}
    old = Weights.decode(safetensors.numpy.save({"a": np.ones(2, np.float32)}, metadata=meta))
    assert old.revision is None and old.progress == (5, -1)
    assert Weights.decode(w.encode()).revision == 9
    pressed = example(Weights, revision=10)
    assert pressed.progress > w.progress > old.progress
    assert example(Weights, revision=0, version=6).progress > w.progress  # a new step: newer, whatever the revision
    assert reason_of(example(Weights, revision=-1).encode) == "bad_value"
    assert reason_of(example(Weights, revision=True).encode) == "wrong_type"


def test_weights_rejections():
    import safetensors.numpy

    w = example(Weights)
    assert reason_of(example(Weights, tensors={"a": np.ones(2, np.float64)}).encode) == "bad_shape"
    assert reason_of(example(Weights, tensors={"a": np.array([np.nan], np.float32)}).encode) == "non_finite"
    assert reason_of(example(Weights, tensors={"a/b": np.ones(2, np.float32)}).encode) == "bad_value"
    assert reason_of(example(Weights, run="a*b").encode) == "bad_value"
    assert reason_of(example(Weights, version=-1).encode) == "bad_value"
    meta = w._metadata()
    f64 = safetensors.numpy.save({"a": np.ones(2, np.float64)}, metadata=meta)
    assert reason_of(Weights.decode, f64) == "bad_shape"
    nan = safetensors.numpy.save({"a": np.array([np.inf], np.float32)}, metadata=meta)
    assert reason_of(Weights.decode, nan) == "non_finite"
    assert reason_of(Weights.decode, safetensors.numpy.save({"a": np.ones(2, np.float32)})) == "missing_field"
    for key, value, reason in [
        ("version", "x", "bad_value"),
        ("version", "-1", "bad_value"),
        ("t_published", "nan", "bad_value"),
        ("t_published", "1e999", "non_finite"),
        ("format", "other", "bad_value"),
        ("run", "a/b", "bad_value"),
        ("revision", "-1", "bad_value"),
        ("revision", "2.5", "bad_value"),
    ]:
        bad = safetensors.numpy.save({"a": np.ones(2, np.float32)}, metadata={**meta, key: value})
        assert reason_of(Weights.decode, bad) == reason, key
    extra = safetensors.numpy.save({"a": np.ones(2, np.float32)}, metadata={**meta, "more": "x"})
    assert reason_of(Weights.decode, extra) == "extra_field"
    data = w.encode()
    assert reason_of(Weights.decode, data[:-3]) == "malformed"
    assert reason_of(Weights.decode, data[:20]) == "malformed"
    assert reason_of(Weights.decode, b"\x80\x02}q\x00.") == "malformed"  # a pickle is never unpickled


# -- keys --------------------------------------------------------------------------------------------------------


def test_keys():
    assert step_key("r1") == "hitl/r1/step"
    assert feedback_key("r1", "oracle") == "hitl/r1/feedback/oracle"
    assert feedback_wildcard("r1") == "hitl/r1/feedback/*"
    assert weights_key("r1") == "hitl/r1/weights"
    assert episode_key("r1") == "hitl/r1/episode"
    assert status_key("r1", "learner") == "hitl/r1/status/learner"
    assert camera_key("r1", "cam0") == "hitl/r1/camera/cam0"
    assert perception_key("r1", "cam0") == "hitl/r1/perception/cam0"
    assert config_key("r1") == "hitl/r1/config"
    assert run_prefix("r1") == "hitl/r1/**"
    p = parse_key("hitl/run-2.a:b/feedback/face_1")
    assert (p.spec.kind, p.run, p.name, p.spec.message) == ("feedback", "run-2.a:b", "face_1", Feedback)
    assert {spec.message for spec in KEYS.values()} == set(MESSAGE_TYPES)


@pytest.mark.parametrize("bad", ["", "a*", "a$b", "a/b", "a#", "a?", "**", "a b", "-a", "x" * 65, "é", "a\n"])
def test_bad_run_names(bad):
    assert reason_of(validate_name, bad) == "bad_value"
    assert reason_of(step_key, bad) == "bad_value"
    assert reason_of(feedback_key, "r1", bad) == "bad_value"


@pytest.mark.parametrize(
    "key",
    [
        "hitl/r1",
        "hitl/r1/nope",
        "other/r1/step",
        "hitl/r1/step/x",
        "hitl/r1/feedback",
        "hitl/r*/step",
        "hitl/r1/feedback/a/b",
        "",
    ],
)
def test_unknown_keys(key):
    assert reason_of(parse_key, key) == "unknown_key"
    assert reason_of(decode, key, example(Step).encode()) == "unknown_key"


def test_decode_checks_run_and_names_against_key():
    assert reason_of(decode, step_key("other"), example(Step).encode()) == "bad_value"
    assert reason_of(decode, feedback_key("r1", "face"), example(Feedback).encode()) == "bad_value"
    assert reason_of(decode, status_key("r1", "actor"), example(ServiceStatus).encode()) == "bad_value"
    assert reason_of(decode, step_key("r1"), example(Feedback).encode()) in ("missing_field", "extra_field")


def test_error_is_a_value_error_with_reason_and_detail():
    e = ProtocolError("bad_value", "seq: -1")
    assert isinstance(e, ValueError) and e.reason == "bad_value" and e.detail == "seq: -1"
    with pytest.raises(AssertionError):
        ProtocolError("no_such_reason")


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        example(Step).seq = 4  # type: ignore[misc]
