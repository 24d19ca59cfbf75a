"""Hypothesis strategies derived from the protocol's own field specs (valid messages of every type)."""

from __future__ import annotations

import dataclasses

import numpy as np
from hypothesis import strategies as st

from common.protocol import (
    NAME_PATTERN,
    TOKEN_PATTERN,
    Box,
    CompressedImage,
    Control,
    Credit,
    CreditedStep,
    EpisodeSummary,
    ExpressionPrediction,
    Feedback,
    Ingest,
    IngestEntry,
    RunConfig,
    Request,
    ServiceStatus,
    Shown,
    ShownStep,
    Step,
    TensorSummary,
    Time,
    Weights,
    WeightsSnapshot,
)
from common.protocol._base import AnyJSON, Embedded, List, Map, Nullable, Obj
from common.protocol._spec import Bool, Bytes64, Float, Int, Spec, Str

TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=20)
JSON_SCALARS = (
    st.none() | st.booleans() | st.integers(-(2**60), 2**60) | st.floats(allow_nan=False, allow_infinity=False) | TEXT
)
ANY_JSON = st.recursive(
    JSON_SCALARS,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(TEXT, children, max_size=4),
    max_leaves=20,
)


def for_spec(spec: Spec) -> st.SearchStrategy:
    if isinstance(spec, Str):
        if spec.enum is not None:
            return st.sampled_from(spec.enum)
        if spec.pattern in (NAME_PATTERN, TOKEN_PATTERN):
            return st.from_regex(spec.pattern[:-1] + r"\Z", fullmatch=True)
        assert spec.pattern is None, spec.pattern
        return st.text(st.characters(exclude_categories=("Cs",)), min_size=spec.min_len, max_size=min(spec.max_len, 20))
    if isinstance(spec, Int):
        if spec.enum is not None:
            return st.sampled_from(spec.enum)
        return st.integers(spec.minimum, spec.maximum)
    if isinstance(spec, Float):
        return st.floats(spec.minimum, spec.maximum, allow_nan=False, allow_infinity=False)
    if isinstance(spec, Bool):
        return st.booleans()
    if isinstance(spec, Bytes64):
        return st.binary(max_size=64)
    if isinstance(spec, List):
        return st.lists(for_spec(spec.item), min_size=spec.min_items, max_size=min(spec.max_items, 8))
    if isinstance(spec, Map):
        keys = st.text(st.characters(exclude_categories=("Cs",)), min_size=1, max_size=min(spec.key_max_len, 12))
        return st.dictionaries(keys, for_spec(spec.value), max_size=min(spec.max_items, 5))
    if isinstance(spec, Nullable):
        return st.none() | for_spec(spec.inner)
    if isinstance(spec, Obj):
        fields = {k: for_spec(v) for k, v in spec.fields.items()}
        return st.builds(spec.cls, **fields) if spec.cls is not None else st.fixed_dictionaries(fields)
    if isinstance(spec, AnyJSON):
        return st.dictionaries(TEXT, ANY_JSON, max_size=5)
    if isinstance(spec, Embedded):
        return messages(spec.cls)
    raise TypeError(spec)


def _fix_step(step: Step) -> Step:
    n = len(step.obs)
    return dataclasses.replace(step, next_obs=(step.next_obs * n)[:n])


def _fix_feedback(fb: Feedback) -> Feedback:
    if fb.shown is None:
        return fb
    shown = [ShownStep(i, float(i)) for i in range(len(fb.shown))]  # ascending, as the cross rule wants
    return dataclasses.replace(fb, shown=shown, actor=fb.actor or "actor-1")


def _fix_shown(msg: Shown) -> Shown:
    return dataclasses.replace(msg, t_shown=max(msg.t_shown, msg.t_action))


def _fix_control(msg: Control) -> Control:
    if msg.command == "pace":
        return dataclasses.replace(msg, rate=msg.rate if msg.rate is not None else 2.0)
    return dataclasses.replace(msg, rate=None)


def _fix_ingest(msg: Ingest) -> Ingest:
    if not msg.credits:
        return msg
    return dataclasses.replace(msg, credits=[dataclasses.replace(c, run=msg.run) for c in msg.credits])


FIXERS = {Step: _fix_step, Feedback: _fix_feedback, Shown: _fix_shown, Control: _fix_control, Ingest: _fix_ingest}


def messages(cls: type) -> st.SearchStrategy:
    if cls is Weights:
        return weights()
    s = st.builds(cls, **{wf.attr: for_spec(wf.spec) for wf in cls.wire_fields()})
    return s.map(FIXERS[cls]) if cls in FIXERS else s


def weights() -> st.SearchStrategy:
    name = st.from_regex(r"[A-Za-z0-9_.]{1,20}\Z", fullmatch=True)
    shape = st.lists(st.integers(0, 5), max_size=3).map(tuple)
    arr = shape.flatmap(
        lambda s: st.builds(
            lambda seed: np.random.default_rng(seed).standard_normal(s).astype(np.float32), st.integers(0, 2**32 - 1)
        )
    )
    return st.builds(
        Weights,
        run=st.from_regex(NAME_PATTERN[:-1] + r"\Z", fullmatch=True),
        incarnation=st.from_regex(TOKEN_PATTERN[:-1] + r"\Z", fullmatch=True),
        version=st.integers(0, 2**53 - 1),
        t_published=st.floats(0, 1e12, allow_nan=False),
        tensors=st.dictionaries(name, arr, max_size=4),
        revision=st.one_of(st.none(), st.integers(0, 2**53 - 1)),
    )


JSON_TYPES = (
    Step,
    Feedback,
    EpisodeSummary,
    ServiceStatus,
    CompressedImage,
    ExpressionPrediction,
    RunConfig,
    Ingest,
    Shown,
    Control,
    Credit,
    WeightsSnapshot,
    Request,
)
ALL_TYPES = JSON_TYPES + (Weights,)


def example(cls: type, **changes):
    """A fixed valid instance of each type, for targeted tests."""
    base = {
        Step: dict(
            run="r1",
            incarnation="actor-1",
            seq=3,
            t_action=1700000000.25,
            episode=1,
            t_in_episode=2,
            obs=[0.0, 1.0],
            action=2,
            reward=-0.01,
            next_obs=[1.0, 1.0],
            terminated=False,
            truncated=False,
            weights_version=4,
            info={"target_distance_before": 3.0, "target_distance_after": 2.0},
        ),
        Feedback: dict(
            run="r1",
            teacher_id="oracle",
            seq=7,
            t_reaction=1700000000.5,
            value=1,
            source="oracle",
            ref_seq=3,
            intended=1,
        ),
        EpisodeSummary: dict(
            run="r1",
            incarnation="actor-1",
            episode=1,
            return_=0.9,
            steps=11,
            feedback_received=5,
            feedback_credited=4,
            weights_version=4,
            t_end=1700000001.0,
        ),
        ServiceStatus: dict(
            run="r1", service="learner", pid=1234, state="ready", t=1700000000.0, counters={"dropped_malformed": 2}
        ),
        CompressedImage: dict(
            timestamp=Time(1700000000, 5), frame_id="cam0", data=b"\xff\xd8\xff\xe0jpeg", format="jpeg"
        ),
        ExpressionPrediction: dict(
            t_capture=1700000000.1,
            frame=12,
            box=Box(10, 20, 64, 64),
            label="happy",
            confidence=0.9,
            probabilities={"happy": 0.9, "neutral": 0.1},
        ),
        Ingest: dict(
            run="r1",
            learner="learner-1",
            seq=0,
            index=0,
            config={"algo": "dqn-tamer"},
            entries=[
                IngestEntry("step", "actor-1", 0, "learned", 1700000000.3),
                IngestEntry("feedback", "oracle", 0, "", 1700000000.4),
                IngestEntry("outcome", "oracle", 0, "credited", 1700000000.4),
            ],
        ),
        RunConfig: dict(run="r1", t_created=1700000000.0, protocol=1, config={"env": "maze", "lr": 0.001}),
        Shown: dict(
            run="r1",
            screen="alice",
            actor="actor-1",
            seq=3,
            t_action=1700000000.25,
            t_shown=1700000000.3,
            t_page=1700000000.29,
            offset=0.01,
            rtt=0.002,
        ),
        Control: dict(run="r1", source="alice", seq=0, t=1700000000.0, command="pace", rate=2.0),
        Credit: dict(
            run="r1",
            teacher_id="alice",
            seq=0,
            value=1,
            status="credited",
            t_reaction=1700000000.5,
            t_credited=1700000000.51,
            actor="actor-1",
            steps=[CreditedStep(2, 0.3), CreditedStep(3, 0.1)],
            lost_mass=0.6,
        ),
        WeightsSnapshot: dict(
            run="r1",
            incarnation="learner-1",
            version=5,
            reason="every",
            t_published=1700000002.0,
            tensors=[TensorSummary("q.0.bias", [4], 0.0, 0.0, 0.0, 0.0, 0.0)],
            weights=b"\x08raw",
        ),
        Request: dict(run="r1", what="snapshot", by="alice", t=1700000002.0),
        Weights: dict(
            run="r1",
            incarnation="learner-1",
            version=5,
            revision=9,
            t_published=1700000002.0,
            tensors={"q.0.weight": np.ones((4, 2), np.float32), "q.0.bias": np.zeros(4, np.float32)},
        ),
    }[cls]
    base.update(changes)
    return cls(**base)
