"""The online delay learner recovers a known skewed lag distribution from simulated feedback."""
import numpy as np

from common.core.delay_learning import DelayLearningConfig, OnlineDelayEM, expected_lag


def simulate(true_probs, n_steps=6000, p_feedback=0.5, h_accuracy=0.85, seed=0, drift_to=None):
    """Steps with a +-1 label the teacher judges by; H predicts it correctly with probability h_accuracy,
    calibrated (|H| = 2 h_accuracy - 1, what a squared-error fit to +-1 targets converges to). Feedback on a step
    arrives after a lag drawn from true_probs. Yields, per arrival, (feedback, predictions of H at the step of each
    candidate lag, validity)."""
    rng = np.random.default_rng(seed)
    L = len(true_probs)
    labels = rng.choice([-1, 1], n_steps)
    h = (2 * h_accuracy - 1) * labels * np.where(rng.random(n_steps) < h_accuracy, 1, -1)
    arrivals = {}
    for t in range(n_steps):
        if rng.random() < p_feedback:
            probs = true_probs if drift_to is None else ((1 - t / n_steps) * np.asarray(true_probs)
                                                         + t / n_steps * np.asarray(drift_to))
            lag = rng.choice(L, p=probs)
            arrivals.setdefault(t + lag, []).append(labels[t])
    for T in sorted(arrivals):
        for f in arrivals[T]:
            steps = T - np.arange(L)
            valid = (steps >= 0) & (steps < n_steps)
            preds = np.where(valid, h[np.clip(steps, 0, n_steps - 1)], 0.0)
            yield f, preds, valid


def test_recovers_a_late_skewed_distribution():
    true = np.array([0.0, 0.05, 0.1, 0.15, 0.3, 0.4, 0.0])
    em = OnlineDelayEM(1, DelayLearningConfig(lags=7, window=3000))
    rows = np.array([0])
    for f, preds, valid in simulate(true, n_steps=12000):
        em.update(rows, np.array([f]), preds[None], valid[None])
    est = em.probs()[0]
    assert np.abs(est - true).sum() < 0.2, est
    assert abs(expected_lag(est[None])[0] - true @ np.arange(7)) < 0.25
    assert est.argmax() == 5 and est[:2].sum() < 0.1


def test_uninformative_predictions_leave_the_start_distribution():
    em = OnlineDelayEM(2, DelayLearningConfig(lags=3), initial=np.array([0.2, 0.5, 0.3]))
    start = em.probs().copy()
    for _ in range(200):
        em.update(np.array([0, 1]), np.array([1, -1]), np.zeros((2, 3)), np.ones((2, 3), bool))
    np.testing.assert_allclose(em.probs(), start, atol=1e-9)


def test_forgetting_follows_a_drifting_observer():
    early = np.array([0.3, 0.6, 0.1, 0.0, 0.0])
    late = np.array([0.0, 0.05, 0.15, 0.5, 0.3])
    em = OnlineDelayEM(1, DelayLearningConfig(lags=5, window=300))
    for f, preds, valid in simulate(early, drift_to=late, n_steps=8000, seed=1):
        em.update(np.array([0]), np.array([f]), preds[None], valid[None])
    est = em.probs()[0]
    # at the end the observer is about `late`; the estimate has followed it past the halfway mixture
    assert expected_lag(est[None])[0] > 2.3, est


def test_rows_are_independent_and_missing_steps_get_no_responsibility():
    em = OnlineDelayEM(2, DelayLearningConfig(lags=3))
    r = em.update(np.array([1]), np.array([1]), np.array([[0.9, -0.9, 0.9]]), np.array([[True, True, False]]))
    assert r[0, 2] == 0 and r[0, 0] > r[0, 1]
    assert em.updates.tolist() == [0, 1]
    np.testing.assert_allclose(em.probs()[0], [1 / 3] * 3)
    assert em.probs()[1, 0] > em.probs()[1, 1] and em.probs()[1, 2] < 1 / 3


def test_per_trial_lags_plug_into_credit_and_leave_other_trials_unchanged():
    """A trial with the paper's assumption gives the same results alone (one shared DelayModel) and batched
    beside trials that assume other lags or learn them (one distribution per trial); the learning trial's
    distribution moves from its start."""
    from dataclasses import replace

    from common.core.observer import ObserverConfig
    from experiments.conditions import agent_for
    from experiments.runner import TrialSpec, run_trials

    obs = ObserverConfig(0.5, (0.0, 0.1, 0.2, 0.7))
    plain = TrialSpec("maze", agent_for("dqn-tamer"), obs, seed=3, layout=0, episodes=6)
    learned = replace(plain, agent=agent_for("dqn-tamer/learned"))
    uniform = replace(plain, agent=agent_for("deep-tamer/uniform"), seed=4)
    alone = run_trials([plain])[0]
    together = run_trials([plain, learned, uniform])
    assert list(alone.returns) == list(together[0].returns)
    lags = [e["mean_lag"] for e in together[1].episodes]
    assert lags[0] != lags[-1] and 0 < lags[-1] < 6
    assert all(abs(e["mean_lag"] - 3.0) < 1e-9 for e in together[2].episodes)  # uniform over 0..6 stays put
    assert together[0].episodes[0]["greedy"] > 0 and together[2].episodes[0]["greedy"] == 0
