"""Credit by time across episode boundaries (issue 24): a press that lands just after the reset, on the move that
reached the goal, is credited to that move; nothing shown after a press ever gets credit."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.agents import TrialBatchAgent
from common.agents.feedback import STATUS_NAMES
from common.agents.config import agent_for
from common.core.credit import credit_weights, onset_weights
from common.core.delay import DelayModel, delay_from_spec
from common.core.delay_model import delay_estimate
from experiments.conditions import agent_for as condition_agent


def credit_in_seconds(agent, t_f: float, value: int, delay, teacher: str = "person"):
    """One feedback through the agent's one door from a teacher credited with `delay` in seconds over the held
    steps' times: (status, the credited steps' times, their weights)."""
    agent.delays.models[0][teacher] = delay
    status, _, _ = agent.feedback_rounds(
        np.array([0]), np.array([np.nan]), np.array([[value]]), np.ones(1, np.int64), np.array([t_f]), [teacher]
    )
    positions, weights = agent.credited(0)
    return STATUS_NAMES[status[0]], agent.history.times_at(0, positions), weights


def episode_then_reset(agent, step_seconds=0.5):
    """Episode 0: steps 0..4, step 4 (action 3 at t = 4, 2 s) reaches the goal (terminal); episode 1 starts at t = 5
    (2.5 s). The rule says +1 of the goal-reaching move, -1 of the others."""
    for k in range(7):
        obs = np.array([[k / 10, 1.0]], np.float32)
        agent.record_steps(
            np.array([0]),
            obs,
            np.array([3 if k == 4 else 0]),
            np.array([float(k == 4)]),
            obs,
            np.array([float(k == 4)]),
            np.array([float(k)]),
            np.array([0 if k <= 4 else 1]),
            np.array([k * step_seconds]),
            np.array([1 if k == 4 else -1]),
        )


def test_a_press_after_the_reset_is_credited_to_the_goal_reaching_move():
    """The paper's credit (lags 0, 1, 2 steps, 1/3 each) at t = 5.5: lag 1 points to step 4, the terminal one."""
    agent = TrialBatchAgent([agent_for("dqn-tamer", None)], 2, 4, [0])
    episode_then_reset(agent)
    out = agent.give_feedback([(0, 5.5, 1)])[0]
    assert out.status == "credited" and out.steps == 3 and out.lost_mass == pytest.approx(0.0)
    credit = agent.last_credit[1]
    times = agent.history.times[0, credit.positions[0, :3]]
    weights = dict(zip(times.tolist(), credit.weights[0, :3].tolist()))
    assert weights == pytest.approx({3.0: 1 / 3, 4.0: 1 / 3, 5.0: 1 / 3})  # the goal-reaching step 4 among them
    assert 3 in agent.history.action[0, credit.positions[0, :3]] and agent.feedback_memory.size[0] == 3


def test_a_learned_delay_credits_the_goal_reaching_move_in_seconds():
    """A press 0.15 s after the reset: the posterior of the learned delay (still Deep TAMER's uniform 0.2-4 s) puts
    the goal-reaching move (0.65 s before) among the steps it credits, above the step the reset showed."""
    agent = TrialBatchAgent([agent_for("dqn-tamer", None)], 2, 4, [0])
    episode_then_reset(agent)
    positions, times = agent.history.held(np.array([0]))
    held = np.isfinite(times[0])
    status, step_times, weights = credit_in_seconds(agent, 2.65, 1, delay_estimate("learned"))
    assert status == "credited"
    by_step = dict(zip(step_times.tolist(), weights.tolist()))
    assert by_step[4.0] > 10 * by_step[5.0] and 6.0 not in by_step  # step 6 appeared at 3.0 s, after the press
    assert sum(by_step.values()) == pytest.approx(1.0) and held.sum() == 7


step_times = st.lists(st.floats(0.01, 2.0), min_size=1, max_size=24).map(lambda g: np.cumsum(g))


@settings(max_examples=60, deadline=None)
@given(starts=step_times, t_f=st.floats(0.0, 60.0), spec=st.sampled_from(["learned", "uniform:0.2,4", "gamma:2,0,0.5"]))
def test_nothing_shown_after_the_press_gets_credit(starts, t_f, spec):
    for reference in ("onset", "interval"):
        w = delay_estimate(spec, reference=reference).weights(t_f, starts)
        assert np.all(w[starts > t_f] == 0) and np.all(w >= 0) and w.sum() <= 1 + 1e-9
    w, lost = credit_weights(t_f, starts, DelayModel((0.2, 0.3, 0.5), 0.5))
    assert np.all(w[starts > t_f] == 0) and w.sum() + lost == pytest.approx(1.0)
    w, _ = onset_weights(t_f, starts, delay_from_spec("gamma:2,0,0.5"))
    assert np.all(w[starts > t_f] == 0)


@settings(max_examples=25, deadline=None)
@given(
    gaps=st.lists(st.floats(0.05, 1.5), min_size=3, max_size=30),
    ends=st.lists(st.booleans(), min_size=30, max_size=30),
    press=st.floats(0.0, 1.0),
    algo=st.sampled_from(["dqn-tamer", "deep-tamer", "dqn-rs"]),
)
def test_the_agents_door_never_credits_a_step_shown_after_the_press(gaps, ends, press, algo):
    """Whatever the episodes and step times, the agent's one door (`feedback_rounds`) gives no step shown after the
    press any weight, learned delay or fixed, shaping or H."""
    agent = TrialBatchAgent([condition_agent(algo)], 2, 4, [0])
    t = np.cumsum(gaps)
    episode = np.cumsum([0] + ends[: len(t) - 1])
    for k, tk in enumerate(t):
        agent.record_steps(
            np.array([0]),
            np.zeros((1, 2)),
            np.array([k % 4]),
            np.zeros(1),
            np.zeros((1, 2)),
            np.array([float(ends[k])]),
            np.array([tk]),
            np.array([episode[k]]),
            np.array([tk]),
            np.array([1 if k % 3 else -1]),
        )
    t_f = float(t[0] + press * (t[-1] - t[0] + 1.0))
    for delay in (delay_estimate("learned"), delay_estimate("uniform:0.2,4", reference="interval")):
        status, times, weights = credit_in_seconds(agent, t_f, 1, delay)
        assert np.all(times <= t_f) and np.all(weights > 0)
        assert status in ("credited", "stale", "ignored")
