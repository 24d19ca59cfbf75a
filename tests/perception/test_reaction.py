"""ReactionDetector on synthetic prediction sequences: smoothing, thresholds, hysteresis, no face."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.perception.faces import FaceBox
from common.perception.reaction import FramePrediction, ReactionConfig, ReactionDetector, synthetic_predictions


def events(seq, fps=30.0, config=ReactionConfig(), **kw):
    return ReactionDetector(config).run(synthetic_predictions(seq, fps=fps, **kw))


def test_held_smile_gives_exactly_one_positive_stamped_with_its_frame():
    seq = ["neutral"] * 10 + ["happy"] * 60 + ["neutral"] * 10
    evs = events(seq)
    assert [e.value for e in evs] == [1]
    e = evs[0]
    assert 10 < e.frame_index <= 10 + 11  # fires within about 0.35 s of the onset
    assert e.t_capture == pytest.approx(e.frame_index / 30.0)  # the triggering frame's capture time
    assert e.confidence >= 0.7 and e.label == "happy"


def test_rearming_needs_the_smile_to_go_away():
    smile = ["happy"] * 30
    assert [e.value for e in events(smile + ["neutral"] * 15 + smile)] == [1, 1]
    # a two-frame flicker does not bring the smoothed probability below the re-arm level
    assert [e.value for e in events(smile + ["neutral"] * 2 + smile)] == [1]


def test_single_frame_spikes_do_not_fire():
    seq = (["neutral"] * 9 + ["happy"]) * 10 + (["neutral"] * 9 + ["sad"]) * 10
    assert events(seq) == []


def test_sad_gives_one_negative_and_can_be_switched_off():
    seq = ["neutral"] * 5 + ["sad"] * 40
    assert [e.value for e in events(seq)] == [-1]
    assert events(seq, config=ReactionConfig(enable_negative=False)) == []


def test_smile_straight_to_frown():
    evs = events(["happy"] * 30 + ["sad"] * 30 + ["happy"] * 30)
    assert [e.value for e in evs] == [1, -1, 1]


def test_no_face_gives_no_feedback_and_does_not_move_the_average():
    assert events([None] * 100) == []
    det = ReactionDetector()
    det.run(synthetic_predictions(["neutral"] * 10))
    before = det.smoothed
    det.run(synthetic_predictions([None] * 5, t0=10 / 30))
    assert det.smoothed == before


def test_short_dropout_keeps_state_long_absence_resets():
    smile = ["happy"] * 30
    # 5 frames (0.17 s) without a face inside a held smile: still one event
    assert [e.value for e in events(smile + [None] * 5 + smile)] == [1]
    # 30 frames (1 s) away: the face coming back smiling is a new reaction
    assert [e.value for e in events(smile + [None] * 30 + smile)] == [1, 1]


def test_behaviour_is_time_based_not_frame_based():
    # 2 s smile, 0.5 s neutral, 2 s smile at 24 and at 30 fps: same events, same times (to a frame)
    out = {}
    for fps in (24.0, 30.0):

        def n(s: float, fps: float = fps) -> int:
            return int(round(s * fps))

        evs = events(["happy"] * n(2) + ["neutral"] * n(0.5) + ["happy"] * n(2), fps=fps)
        out[fps] = [(e.value, e.t_capture) for e in evs]
    assert [v for v, _ in out[24.0]] == [v for v, _ in out[30.0]] == [1, 1]
    for (_, a), (_, b) in zip(out[24.0], out[30.0]):
        assert abs(a - b) <= 1 / 24


def test_low_confidence_smile_does_not_fire():
    # happy at 0.65 with the rest spread: positive polarity never reaches 0.7
    assert events(["happy"] * 60, confidence=0.65) == []
    assert [e.value for e in events(["happy"] * 60, confidence=0.8)] == [1]


def test_no_smoothing_fires_on_the_first_frame():
    evs = events(["happy"], config=ReactionConfig(tau_s=0.0))
    assert [(e.value, e.frame_index) for e in evs] == [(1, 0)]


def test_label_names_from_other_models_map_to_polarity():
    labels = ("neutral", "anger", "contempt", "disgust", "fear", "happy", "sadness", "surprise")
    for lab, value in [
        ("happy", 1),
        ("contempt", -1),
        ("sadness", -1),
        ("anger", -1),
        ("surprise", None),
        ("neutral", None),
    ]:
        evs = events([lab] * 30, labels=labels)
        assert [e.value for e in evs] == ([] if value is None else [value]), lab


def test_config_is_validated():
    with pytest.raises(ValueError):
        ReactionConfig(on_threshold=0.3, off_threshold=0.5)
    with pytest.raises(ValueError):
        ReactionConfig(on_threshold=0.5, off_threshold=0.2)  # both polarities could be over it


def test_out_of_order_timestamps_do_not_break_it():
    det = ReactionDetector()
    box = FaceBox(0, 0, 5, 5)
    p = lambda i, t: FramePrediction(i, t, box, ("happy", "neutral"), (1.0, 0.0))  # noqa: E731
    assert det.update(p(0, 1.0)) is None
    for i, t in enumerate([0.5, 0.9, 1.0, 1.2, 1.3, 1.4, 1.5], start=1):
        det.update(p(i, t))
    assert det.smoothed[0] > 0.6


labels_or_none = st.sampled_from(["happy", "sad", "neutral", "surprise", None])


@settings(max_examples=200, deadline=None)
@given(st.lists(labels_or_none, max_size=200), st.sampled_from([15.0, 24.0, 30.0, 60.0]))
def test_properties_on_random_sequences(seq, fps):
    evs = events(seq, fps=fps)
    # deterministic
    assert [(e.value, e.frame_index) for e in evs] == [(e.value, e.frame_index) for e in events(seq, fps=fps)]
    # an event fires on a frame showing its expression, never on a frame without a face
    for e in evs:
        assert seq[e.frame_index] == ("happy" if e.value == 1 else "sad")
    # each +1 needs its own run of happy frames (re-arming needs the smile to go away)
    runs = sum(1 for i, s in enumerate(seq) if s == "happy" and (i == 0 or seq[i - 1] != "happy"))
    assert sum(e.value == 1 for e in evs) <= runs
    # and consecutive +1 events are separated by something other than a smile
    pos = [e.frame_index for e in evs if e.value == 1]
    for a, b in zip(pos, pos[1:]):
        assert any(s != "happy" for s in seq[a:b])
