"""A person's feedback on what their screen showed (the console): credit in seconds over the on-screen intervals
of the held steps, by the one credit function (`common.core.credit`), then the agent's D_local step."""
from __future__ import annotations

import numpy as np

from common.agents.agent import FeedbackOutcome, TrialBatchAgent
from common.core.credit import credit_weights, onset_weights


def give_screen_feedback(agent: TrialBatchAgent, i: int, t_feedback: float, value: int, step_times, starts, ends,
                         delay, reference: str = "interval") -> tuple[FeedbackOutcome, np.ndarray]:
    """Feedback from a person who watched the steps on a screen (the console): the held steps recorded at
    `step_times` were on screen during [starts, ends) seconds, oldest first; credit them in seconds with
    `delay` (any distribution with a CDF), by the same credit function, over each step's interval
    (`reference` "interval", Deep TAMER's) or at its onset ("onset": `common.core.credit.onset_weights`). Mass on
    steps no longer held is lost. Returns the outcome and the weight given to each listed step."""
    if value not in (-1, 1):
        raise ValueError(f"feedback must be -1 or +1, got {value!r}")
    step_times = np.asarray(step_times, np.float64)
    weights = np.zeros(len(step_times), np.float64)
    row = np.array([i], np.int64)
    pos, times = agent.history._chronological(row)
    held = {float(t): int(p) for t, p in zip(times[0], pos[0]) if np.isfinite(t)}
    at = np.array([held.get(float(t), -1) for t in step_times], np.int64)
    if agent.shaping[i]:  # naive shaping: the newest step shown at or before the feedback, if still held
        on = np.flatnonzero((np.asarray(starts) <= t_feedback) & (at >= 0))
        if not len(on):
            return FeedbackOutcome("stale", 0, 1.0), weights
        weights[on[-1]] = 1.0
        agent.replay.add_reward(row, agent.history.slot[row, at[on[-1:]]], np.array([value], np.float32))
        return FeedbackOutcome("credited", 1, 0.0), weights
    if not agent.train_h[i]:
        return FeedbackOutcome("ignored"), weights
    if not len(step_times):
        return FeedbackOutcome("stale", 0, 1.0), weights
    episodes = np.where(at >= 0, agent.history.episode[i, np.maximum(at, 0)], -1)
    if reference == "onset":
        w, _ = onset_weights(t_feedback, starts, delay, episodes=episodes)
    else:
        w, _ = credit_weights(t_feedback, starts, delay, ends=ends, episodes=episodes)
    weights = np.where(at >= 0, w, 0.0)
    k = np.flatnonzero(weights > 0)
    lost = max(0.0, 1.0 - float(weights.sum()))
    if not len(k):
        return FeedbackOutcome("stale", 0, lost), weights
    p = at[k][None, :]
    obs, act = agent.history.obs[row[:, None], p], agent.history.action[row[:, None], p]
    agent._learn_local(row, np.array([len(k)]), obs, act, np.full((1, len(k)), value, np.float32),
                      weights[k][None, :].astype(np.float32))
    return FeedbackOutcome("credited", int(len(k)), lost), weights
