import numpy as np
import pytest

import scipy.stats

from common.core.credit import credit_weights, onset_weights
from common.core.delay import DelayModel, delay_from_spec, parse_probs

UNIFORM3 = DelayModel((1 / 3, 1 / 3, 1 / 3))


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


def test_several_feedbacks_in_flight_are_independent():
    times = np.arange(6.0)
    a, _ = credit_weights(3.5, times, UNIFORM3)
    b, _ = credit_weights(5.5, times, UNIFORM3)
    assert np.flatnonzero(a).tolist() == [1, 2, 3] and np.flatnonzero(b).tolist() == [3, 4, 5]


def test_time_going_backwards_is_refused():
    with pytest.raises(ValueError, match="ascending"):
        credit_weights(3.0, [2.0, 1.0], UNIFORM3)


def test_credited_across_an_episode_boundary():
    """Steps 0..5; episode 0 is steps 0..3 (step 3 reached the goal), episode 1 starts at step 4 (t=4). A reaction
    at 4.5 refers to steps 4, 3, 2 (lags 0, 1, 2) whatever their episode: the goal-reaching move keeps its share."""
    times = np.arange(6.0)
    w, lost = credit_weights(4.5, times, UNIFORM3)
    np.testing.assert_allclose(w, [0, 0, 1 / 3, 1 / 3, 1 / 3, 0])
    assert lost == pytest.approx(0.0)


def test_the_step_model_on_the_step_clock_is_the_papers_lag_counting():
    probs = (0.3, 0.6, 0.1)
    for t_f in (5.5, 5.0, 5.999):
        w, _ = credit_weights(t_f, np.arange(10.0), DelayModel(probs))
        for lag, p in enumerate(probs):
            assert w[5 - lag] == pytest.approx(p)  # lag i steps refers to step k - i


def test_uniform_seconds_integrated_over_unequal_intervals():
    delay = delay_from_spec("uniform:0.2,4")  # Deep TAMER's default
    starts = np.array([10.0, 10.5, 12.0, 13.0])  # shown 0.5 s, 1.5 s, 1 s, still shown
    w, lost = credit_weights(14.0, starts, delay)
    # t_f - D is uniform on [10.0, 13.8): 3.8 s of mass spread over the intervals by their overlap.
    np.testing.assert_allclose(w, np.array([0.5, 1.5, 1.0, 0.8]) / 3.8)
    assert lost == pytest.approx(0.0, abs=1e-12)
    # Explicit ends (a blank screen between steps 1 and 2): the mass in the gap is lost.
    ends = np.array([10.5, 11.0, 13.0, np.inf])
    w, lost = credit_weights(14.0, starts, delay, ends=ends)
    np.testing.assert_allclose(w, np.array([0.5, 0.5, 1.0, 0.8]) / 3.8)
    assert lost == pytest.approx(1.0 / 3.8)


def test_gamma_delay_weights_are_its_cdf_differences():
    delay = scipy.stats.gamma(2.0, scale=0.4)
    starts = np.array([0.0, 0.3, 0.9, 1.0, 2.2])
    t_f = 2.5
    w, lost = credit_weights(t_f, starts, delay)
    ends = np.append(starts[1:], np.inf)
    expected = delay.cdf(t_f - starts) - delay.cdf(t_f - ends)
    np.testing.assert_allclose(w, expected, rtol=1e-12)
    assert w.sum() + lost == pytest.approx(1.0)
    assert lost == pytest.approx(1 - delay.cdf(t_f - starts[0]))
    assert delay_from_spec("gamma:2.0,0,0.4").cdf(1.0) == pytest.approx(delay.cdf(1.0))


def test_batched_rows_equal_one_at_a_time():
    rng = np.random.default_rng(0)
    delay = DelayModel((0.2, 0.5, 0.3), unit=0.7)
    starts = np.sort(rng.uniform(0, 10, (5, 8)), axis=1)
    starts[1, 5:] = np.inf  # a row holding fewer steps
    t_f = rng.uniform(2, 12, 5)
    w, lost = credit_weights(t_f, starts, delay)
    for i in range(5):
        k = np.isfinite(starts[i])
        wi, li = credit_weights(t_f[i], starts[i, k], delay)
        np.testing.assert_array_equal(w[i, k], wi)
        assert lost[i] == li


@pytest.mark.parametrize("spec", ["uniform:4,0.2", "gamma:-1", "nosuch:1", "uniform:a,b", "steps:0.5"])
def test_bad_delay_specs_are_one_line_errors(spec):
    with pytest.raises(ValueError, match="delay"):
        delay_from_spec(spec)


@pytest.mark.parametrize("bad", ["0.3,0.3", "a,b", "", "-0.5,1.5", "nan,1"])
def test_probability_parsing_rejects_bad_input(bad):
    with pytest.raises(ValueError):
        parse_probs(bad, "delay-probs")


class _CdfOnly:
    """A delay seen only through its CDF / mass_between: credit's general path."""

    def __init__(self, delay):
        self.mass_between = delay.mass_between
        self.cdf = delay.cdf


@pytest.mark.parametrize(
    "probs,unit",
    [
        ((1 / 3, 1 / 3, 1 / 3), 1.0),
        ((0.1, 0.2, 0.3, 0.25, 0.15), 1.0),
        ((0.3, 0.6, 0.1), 0.25),
        ((0.5, 0.3, 0.2), 0.7),
        ((1.0,), 1.0),
    ],
)
def test_point_mass_fast_path_equals_the_general_path_bit_for_bit(probs, unit):
    from common.core.delay import RowDelays

    rng = np.random.default_rng(len(probs))
    delay = DelayModel(probs, unit)
    row_probs = rng.dirichlet(np.ones(len(probs)), size=6)
    for trial in range(40):
        # 6 trials x 12 held steps: the step clock (k, k + 1, ...) or unequal durations, with +inf padding (fewer
        # steps held); feedback stamps between and beyond them.
        gaps = np.ones((6, 12)) if trial % 2 else rng.choice([0.2, 0.5, 1.0, 2.0, 3.0], size=(6, 12))
        starts = np.cumsum(gaps, axis=1) + rng.integers(0, 50, size=(6, 1))
        starts[rng.random(6) < 0.3, : rng.integers(1, 12)] = np.inf
        starts = np.sort(starts, axis=1)
        t_f = np.where(np.isfinite(starts[:, -1]), starts[:, -1], 0) - rng.uniform(-2, 6, size=6)
        for d, general in (
            (delay, _CdfOnly(delay)),
            (RowDelays(row_probs, unit), _CdfOnly(RowDelays(row_probs, unit))),
        ):
            fast_w, fast_lost = credit_weights(t_f, starts, d)
            w, lost = credit_weights(t_f, starts, general)
            assert np.array_equal(fast_w, w) and np.array_equal(fast_lost, lost)
            for k in range(6):  # one feedback alone (1-d) as the console and the learner ask
                one = d if d is delay else RowDelays(row_probs[k : k + 1], unit)
                w1, lost1 = credit_weights(t_f[k], starts[k], one)
                assert np.array_equal(w1, fast_w[k]) and lost1 == fast_lost[k]


def test_onset_credit_shares_a_uniform_delay_equally_among_the_steps_that_appeared_within_it():
    """A person reacting 0.3-1.5 s after a step appeared: every step whose onset lies 0.3-1.5 s before the press
    is equally likely to be the one rated; steps that appeared earlier or later get nothing."""
    starts = np.array([0.0, 0.4, 0.8, 1.2, 1.6, 1.9])  # 2.5 steps/s; the last appeared after the press
    w, lost = onset_weights(1.95, starts, scipy.stats.uniform(loc=0.3, scale=1.2))
    np.testing.assert_allclose(w, [0, 0, 1 / 3, 1 / 3, 1 / 3, 0])  # 1.95 s and 0.05 s after their onsets: outside
    assert lost == pytest.approx(0.0)


def test_onset_credit_follows_the_density():
    starts = np.array([0.0, 1.0, 2.0, 3.0])
    delay = scipy.stats.gamma(2.0, scale=0.5)
    w, lost = onset_weights(3.5, starts, delay)
    density = delay.pdf(3.5 - starts)
    np.testing.assert_allclose(w, density / density.sum())
    assert lost == pytest.approx(0.0)


def test_onset_credit_of_a_press_with_no_step_in_reach_is_all_lost():
    w, lost = onset_weights(10.0, np.array([0.0, 1.0]), scipy.stats.uniform(loc=0.2, scale=3.8))
    assert not w.any() and lost == 1.0


def test_onset_credit_differs_from_the_interval_reading_where_the_person_reacts_to_onsets():
    """The interval reading (Deep TAMER's) gives part of the mass to the step before the true one; the onset
    reading does not when only one onset is in reach."""
    starts = np.array([0.0, 0.5, 1.0])
    delay = scipy.stats.uniform(loc=0.3, scale=0.2)  # reacts 0.3-0.5 s after the onset
    t = 1.0 + 0.45  # a reaction to the step that appeared at 1.0
    onset, _ = onset_weights(t, starts, delay)
    interval, _ = credit_weights(t, starts, delay)
    np.testing.assert_allclose(onset, [0, 0, 1])
    assert interval[1] > 0  # [t - 0.5, t - 0.3] reaches back into the step before


def test_onset_credit_needs_a_density():
    with pytest.raises(ValueError, match="density"):
        onset_weights(1.0, np.array([0.0]), DelayModel((0.5, 0.5)))
