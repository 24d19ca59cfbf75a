"""The delay learned online in seconds (common/core/delay_model.py) and its use per trial (feedback.py)."""

import json
from dataclasses import replace

import numpy as np
import pytest

from common.core.delay import delay_from_spec
from common.core.delay_model import (
    FixedDelay,
    LearnedDelay,
    LearnedDelayConfig,
    check_delay_estimate_spec,
    delay_estimate,
    estimate_from_state,
    polarity_likelihood,
)

STEPS = np.arange(0.0, 200.0, 0.5)  # a step every 0.5 s


def feed(model, spec, n, rng, p_minus=0.6):
    """n presses of a person with delay `spec` (s, from a step's onset) rating steps of random polarity."""
    dist = delay_from_spec(spec)
    polarity = np.where(rng.random(len(STEPS)) < p_minus, -1, 1)
    for k in np.sort(rng.choice(np.arange(40, len(STEPS) - 20), n, replace=False)):
        t_f = STEPS[k] + min(float(dist.ppf(rng.random())), 6.0)
        shown = slice(max(0, k - 31), np.searchsorted(STEPS, t_f, side="right"))
        model.observe(t_f, STEPS[shown], None, polarity_likelihood(polarity[k], polarity[shown]))


def test_the_prior_is_deep_tamers_uniform_and_stays_when_nothing_is_learned():
    model = delay_estimate("learned")
    s = model.summary()
    assert s["feedbacks"] == 0 and 0.2 < s["p10_s"] < s["median_s"] < s["p90_s"] < 4.0
    assert s["median_s"] == pytest.approx(2.1, abs=0.05)
    # Feedback that every candidate explains alike (H knows nothing, the rule says nothing) moves nothing.
    for t in np.arange(20.0, 60.0, 0.7):
        assert not model.observe(t, STEPS[STEPS <= t][-30:], None, np.full(30, 0.5))
    assert model.summary()["median_s"] == s["median_s"] and model.summary()["feedbacks"] > 50


def test_weights_are_a_posterior_over_steps_shown_before_the_press():
    model = delay_estimate("learned")
    w = model.weights(5.0, STEPS[:20])
    assert w.sum() == pytest.approx(1.0) and np.all(w[STEPS[:20] > 5.0] == 0)
    assert np.all(w[(5.0 - STEPS[:20] > 0.25) & (5.0 - STEPS[:20] < 3.9)] > 0.05)  # the prior's 0.2-4 s
    assert model.weights(5.0, np.array([5.5, 6.0])).sum() == 0  # nothing shown yet: no credit


@pytest.mark.parametrize("spec", ["gamma:4,0,0.25", "lognorm:0.6,0,0.9"])
def test_recovers_a_known_delay_from_a_model_of_the_rated_event(spec):
    model = LearnedDelay()
    feed(model, spec, 300, np.random.default_rng(0))
    truth = float(delay_from_spec(spec).ppf(0.5))
    assert abs(model.summary()["median_s"] - truth) <= 0.15 * truth


def test_follows_a_person_who_slows_down():
    model = LearnedDelay()
    rng = np.random.default_rng(1)
    feed(model, "lognorm:0.3,0,0.5", 200, rng)
    assert model.summary()["median_s"] < 0.8
    feed(model, "lognorm:0.3,0,2", 150, rng)
    assert abs(model.summary()["median_s"] - 2.0) <= 0.2 * 2.0


def test_state_round_trips_through_json_and_a_profile_starts_from_the_estimate():
    model = LearnedDelay()
    feed(model, "gamma:4,0,0.25", 60, np.random.default_rng(2))
    again = estimate_from_state(json.loads(json.dumps(model.state())))
    assert again.summary() == model.summary()
    np.testing.assert_array_equal(again.density()[1], model.density()[1])
    profile = LearnedDelay.from_state(json.loads(json.dumps(model.state(window=False))))
    assert profile.summary()["median_s"] == pytest.approx(model.summary()["median_s"], rel=0.05)
    assert len(json.dumps(model.state(window=False))) < 4000  # a small file
    edges, probs = model.density()
    assert len(edges) == len(probs) + 1 and edges[-1] == 6.0 and probs.sum() == pytest.approx(1.0)


def test_fixed_delays_keep_the_credit_functions_weights():
    fixed = delay_estimate("uniform:0.2,4", reference="interval")
    assert isinstance(fixed, FixedDelay) and not fixed.observe(3.0, STEPS[:8])
    w = fixed.weights(5.0, STEPS[:12])  # steps shown 0..5.5 s cover every delay of 0.2-4 s
    assert w.sum() == pytest.approx(1.0) and np.all(w[STEPS[:12] >= 4.9] == 0)
    assert fixed.weights(3.0, STEPS[:8]).sum() == pytest.approx(2.8 / 3.8)  # steps before 0 s: mass lost
    assert fixed.summary()["median_s"] == pytest.approx(2.1)
    assert estimate_from_state(fixed.state()).summary() == fixed.summary()


@pytest.mark.parametrize("spec", ["learned:nosuch:1", "uniform:4,1", "mix:0.5*steps:1", "mix:x*gamma:2,0,1"])
def test_bad_specs_are_one_line_errors(spec):
    with pytest.raises(ValueError, match="delay"):
        check_delay_estimate_spec(spec)


def test_bad_config_is_refused():
    with pytest.raises(ValueError):
        LearnedDelayConfig(reference="middle")
    with pytest.raises(ValueError):
        LearnedDelayConfig(forget=0)


def test_per_trial_delays_plug_into_the_runner_and_leave_other_trials_unchanged():
    """A trial with the paper's assumption gives the same results alone and batched beside a trial that learns
    its teacher's delay in seconds; the learning trial's median moves from the prior's 2.1 s."""
    from common.core.observer import ObserverConfig
    from experiments.conditions import agent_for
    from experiments.runner import TrialSpec, run_trials

    obs = ObserverConfig(0.5, (0.0, 0.1, 0.2, 0.7))
    plain = TrialSpec("maze", agent_for("dqn-tamer"), obs, seed=3, layout=0, episodes=3)
    learned = replace(
        plain, agent=replace(agent_for("dqn-tamer"), learn_delay=True), observer=replace(obs, delay_s="gamma:4,0,0.25")
    )
    alone = run_trials([plain])[0]
    together = run_trials([plain, learned])
    assert list(alone.returns) == list(together[0].returns)
    medians = [e["delay_median_s"] for e in together[1].episodes]
    assert together[0].episodes[-1]["delay_median_s"] is None and abs(medians[-1] - 2.1) > 0.3
    assert together[1].delay["feedbacks"] == sum(e["feedback_given"] for e in together[1].episodes)
    assert together[0].delay["learned"] is False and together[0].delay["median_s"] == pytest.approx(0.5)


def test_presses_the_event_model_does_not_explain_leave_the_estimate_broad():
    """A teacher whose values have nothing to do with the rule: no delay explains them better than another, so
    the density stays spread over the range (it does not collapse onto whatever credit it gave)."""
    rng = np.random.default_rng(3)
    model = LearnedDelay()
    polarity = np.where(rng.random(len(STEPS)) < 0.6, -1, 1)
    for k in np.sort(rng.choice(np.arange(40, len(STEPS) - 20), 300, replace=False)):
        t_f = STEPS[k] + rng.gamma(4, 0.25)
        shown = slice(max(0, k - 31), np.searchsorted(STEPS, t_f, side="right"))
        model.observe(t_f, STEPS[shown], None, polarity_likelihood(int(rng.choice([-1, 1])), polarity[shown]))
    s = model.summary()
    assert s["p90_s"] - s["p10_s"] > 3.0, s
