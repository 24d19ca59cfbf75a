import numpy as np
import pytest

from common.credit import StepHistory, credit_weights
from common.delay import DelayModel, parse_probs

UNIFORM3 = DelayModel.uniform(3)


def test_uniform_over_zero_to_two_steps_gives_a_third_to_each_of_the_last_three():
    weights, lost = credit_weights(10.5, np.arange(11.0), UNIFORM3)
    np.testing.assert_allclose(weights[-3:], [1 / 3, 1 / 3, 1 / 3])
    assert weights[:-3].sum() == 0 and lost == pytest.approx(0.0)


def test_feedback_between_steps_credits_steps_taken_before_it_only():
    # Feedback at 5.5 while steps at 0..10 exist (the history ran ahead): steps 3, 4, 5.
    weights, lost = credit_weights(5.5, np.arange(11.0), UNIFORM3)
    assert np.flatnonzero(weights).tolist() == [3, 4, 5]


def test_unequal_step_durations():
    # Steps at 0, 0.2, 1.0, 3.0 (actions taken at those times), feedback at 3.1, lags 0, 1, 2 (units 1):
    # lag 0 -> cause time 3.1 -> step at 3.0; lag 1 -> 2.1 -> step at 1.0; lag 2 -> 1.1 -> step at 1.0.
    model = DelayModel((0.5, 0.3, 0.2))
    weights, lost = credit_weights(3.1, [0.0, 0.2, 1.0, 3.0], model)
    np.testing.assert_allclose(weights, [0.0, 0.0, 0.5, 0.5])
    assert lost == pytest.approx(0.0)
    # A long pause after step 0.2 means a lag-0 reaction at 0.9 belongs to the step at 0.2.
    weights, _ = credit_weights(0.9, [0.0, 0.2, 1.0, 3.0], DelayModel((1.0,)))
    np.testing.assert_allclose(weights, [0.0, 1.0, 0.0, 0.0])


def test_real_seconds_unit():
    model = DelayModel((0.3, 0.6, 0.1), unit=0.25)  # lags 0, 0.25, 0.5 s
    weights, lost = credit_weights(100.6, [100.0, 100.25, 100.5], model)
    np.testing.assert_allclose(weights, [0.1, 0.6, 0.3])


def test_stale_feedback_is_lost_not_misassigned():
    # The held steps are all newer than anything the feedback can refer to.
    weights, lost = credit_weights(20.5, [30.0, 31.0], UNIFORM3)
    assert weights.sum() == 0 and lost == pytest.approx(1.0)
    # The newest step's interval is open: a late reaction with nothing newer held goes to it.
    weights, lost = credit_weights(20.5, [10.0, 11.0], UNIFORM3)
    np.testing.assert_allclose(weights, [0.0, 1.0])
    weights, lost = credit_weights(11.5, [10.0, 11.0], UNIFORM3)  # lag 2 points before the oldest step
    np.testing.assert_allclose(weights, [1 / 3, 1 / 3])
    assert lost == pytest.approx(1 / 3)


def test_history_forgets_old_steps_and_reports_stale():
    h = StepHistory(capacity=3)
    for k in range(10):
        h.push(float(k), f"step{k}")
    assert len(h) == 3
    result = h.credit(9.5, UNIFORM3)
    assert [p for p, _ in result.entries] == ["step7", "step8", "step9"]
    stale = h.credit(5.5, UNIFORM3)
    assert not stale.credited and stale.lost_mass == pytest.approx(1.0)


def test_several_feedbacks_in_flight_are_independent():
    h = StepHistory(capacity=16)
    for k in range(6):
        h.push(float(k), k)
    a = h.credit(3.5, UNIFORM3)
    b = h.credit(5.5, UNIFORM3)
    assert [p for p, _ in a.entries] == [1, 2, 3]
    assert [p for p, _ in b.entries] == [3, 4, 5]
    assert h.latest_at(4.2) == 4


def test_history_rejects_time_going_backwards():
    h = StepHistory()
    h.push(2.0, "a")
    with pytest.raises(ValueError, match="older"):
        h.push(1.0, "b")


@pytest.mark.parametrize("bad", ["0.3,0.3", "a,b", "", "-0.5,1.5", "nan,1"])
def test_probability_parsing_rejects_bad_input(bad):
    with pytest.raises(ValueError):
        parse_probs(bad, "delay-probs")
