"""One step of Algorithm 2 of the paper, written once for every driver: the in-process runner (batched, on
the virtual clock), the live learner (one trial, from Zenoh inputs) and `replay retrain` (from a log).

For each step of each trial, in this order:

1. `credit`: the feedback that arrived before this step's action is credited through the agent's one door
   (`feedback_rounds`) by timestamp over the intervals the held steps were shown, whatever their episode, with
   its teacher's delay from the agent's registry (the step clock's assumed lags, or a delay in seconds, over a
   person's screen where there is one): D_local, an H update per feedback, D_global grows; or, for shaping
   agents, added to the newest shown step's reward;
2. `step`: the step's transition is recorded (replay, the step history that credit reads);
3. the every-b-steps updates run (a Q minibatch from replay, an H minibatch from D_global), then the
   target network syncs when due.

The live learner cannot know of a feedback before the next step's action has arrived (its stamp must be
placed between two actions), so this is the order in which both drivers can see their inputs; given the same
ordered inputs they therefore end with the same weights (tests/experiments/test_one_loop.py). Acting is not
part of it: it changes no learning state (exploration draws are counter-based).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.agents.agent import TrialBatchAgent
from common.agents.feedback import Screen


@dataclass
class FeedbackRound:
    """Per trial asked about: status code (`agent.STATUS_NAMES`), steps credited, mass lost."""

    status: np.ndarray
    steps: np.ndarray
    lost: np.ndarray


class StepLoop:
    def __init__(self, agent: TrialBatchAgent):
        self.agent = agent

    def credit(
        self,
        rows: np.ndarray,
        t_feedback: np.ndarray,
        values: np.ndarray,
        counts: np.ndarray | None = None,
        seconds: np.ndarray | None = None,
        teachers: list[str] | None = None,
        screens: list[Screen | None] | None = None,
    ) -> FeedbackRound:
        """Feedback that arrived before the next action: values[k, r] (+-1) for trial rows[k], stamped
        t_feedback[k] on the step clock (`seconds[k]` on the teacher's clock, for a delay in seconds), for
        r < counts[k] (rounds in arrival order; values may be 1-d for one round each), from `teachers[k]` (default:
        the trial's one teacher), seen on `screens[k]` (a person's; None: none)."""
        values = np.asarray(values, np.int64)
        if values.ndim == 1:
            values = values[:, None]
        if counts is None:
            counts = np.ones(len(rows), np.int64)
        return FeedbackRound(
            *self.agent.feedback_rounds(
                np.asarray(rows, np.int64),
                np.asarray(t_feedback, np.float64),
                values,
                counts,
                None if seconds is None else np.asarray(seconds, np.float64),
                teachers,
                screens,
            )
        )

    def step(
        self,
        rows: np.ndarray,
        obs,
        actions,
        rewards,
        next_obs,
        terminated,
        t_action,
        episodes,
        seconds=None,
        polarity=None,
    ) -> None:
        """Trials `rows` (distinct) took a step at t_action (`seconds` on the teacher's clock; the task rule says
        `polarity` of it): record it, then the every-b-steps updates."""
        agent = self.agent
        agent.record_steps(rows, obs, actions, rewards, next_obs, terminated, t_action, episodes, seconds, polarity)
        if len(rows) == agent.B:
            agent.update()
        else:
            active = np.zeros(agent.B, bool)
            active[rows] = True
            agent.update(active)
