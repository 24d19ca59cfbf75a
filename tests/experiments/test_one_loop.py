"""One step loop: the in-process runner and the live learner's core, given the same ordered inputs, end with
the same weights bit for bit, for all four agents."""

import pytest

from common.agents import ALGOS
from common.agents.config import AgentConfig
from common.core.observer import ObserverConfig
from common.protocol import Feedback, Step
from experiments.runner import TrialSpec, run_trials
from common.core.task import Task
from services.common.config import LearnerConfig
from services.learner.core import LearnerCore

RUN = "one-loop"
T0, PERIOD = 1.7e9, 0.01  # wall clock of the live run: step k acts at T0 + k * PERIOD


def agent_of(config: LearnerConfig) -> AgentConfig:
    """The learner's agent config (its `__post_init__` resolves it from the algo)."""
    if config.agent is None:
        raise ValueError("LearnerConfig.agent is not resolved")
    return config.agent


def runner_inputs(spec: TrialSpec):
    inputs = []
    result = run_trials([spec], on_input=lambda i, kind, rec: inputs.append((kind, rec)))[0]
    return result, inputs


def rule_info(polarity: int) -> dict:
    """A step's info from which the maze's rule says `polarity` (what the actor sends)."""
    return {"target_distance_before": 2.0, "target_distance_after": 1.0 if polarity > 0 else 3.0}


def to_messages(inputs, t0: float = T0, period: float = PERIOD) -> list:
    """The runner's inputs as the actor's Steps and a teacher's Feedback, stamped on a wall clock (a reaction
    at virtual time k + 0.5 is stamped half-way between the wall times of actions k and k + 1)."""
    out: list[Step | Feedback] = []
    seq_fb, t_in = 0, 0
    for kind, rec in inputs:
        if kind == "step":
            k = int(rec["t"])
            out.append(
                Step(
                    run=RUN,
                    incarnation="actor-1",
                    seq=k,
                    t_action=t0 + k * period,
                    episode=rec["episode"],
                    t_in_episode=t_in,
                    obs=rec["obs"].tolist(),
                    action=rec["action"],
                    reward=rec["reward"],
                    next_obs=rec["next_obs"].tolist(),
                    terminated=rec["terminated"],
                    truncated=rec["truncated"],
                    weights_version=0,
                    info=rule_info(rec["polarity"]),
                )
            )
            t_in = 0 if rec["terminated"] or rec["truncated"] else t_in + 1
        else:
            out.append(
                Feedback(
                    run=RUN,
                    teacher_id="oracle",
                    seq=seq_fb,
                    t_reaction=t0 + rec["t"] * period,
                    value=rec["value"],
                    source="oracle",
                )
            )
            seq_fb += 1
    return out


@pytest.mark.parametrize("algo", ALGOS)
def test_runner_and_live_learner_end_with_identical_weights(algo):
    config = LearnerConfig(run=RUN, task=Task(env="maze", layout=2, seed=11), algo=algo)
    agent = agent_of(config)
    spec = TrialSpec(
        "maze", agent, ObserverConfig(p_feedback=0.6, delay_probs=(0.3, 0.6, 0.1)), seed=11, layout=2, episodes=8
    )
    result, inputs = runner_inputs(spec)
    n_feedback = sum(kind == "feedback" for kind, _ in inputs)
    assert result.total_steps > 80 and n_feedback > 40
    core = LearnerCore(config)
    credited = 0
    for msg in to_messages(inputs):
        if isinstance(msg, Step):
            results, _ = core.on_step(msg)
        else:
            results = core.on_feedback(msg)
        credited += sum(r.status == "credited" for r in results)
    core.end()
    assert core.steps_learned == result.total_steps
    live = core.policy_weights()
    assert set(live) == set(result.weights)
    for name, w in result.weights.items():
        assert live[name].tobytes() == w.tobytes(), name
    assert (credited > 0) == (algo != "dqn")
    assert sum(e["feedback_credited"] for e in result.episodes) == credited


def test_with_a_delay_learned_in_seconds_too():
    """DQN-TAMER learning its teacher's delay: the runner's clock of 0.5 s per step and the live learner's wall
    clock (the same seconds) credit every feedback with the same learned posterior, across episodes."""
    from dataclasses import replace

    config = LearnerConfig(
        run=RUN,
        task=Task(env="maze", layout=2, seed=11),
        algo="dqn-tamer",
        agent=replace(agent_of(LearnerConfig(run=RUN)), learn_delay=True),
    )
    spec = TrialSpec(
        "maze",
        agent_of(config),
        ObserverConfig(p_feedback=0.6, delay_probs=(0.3, 0.6, 0.1)),
        seed=11,
        layout=2,
        episodes=8,
        step_seconds=0.5,
    )
    result, inputs = runner_inputs(spec)
    core = LearnerCore(config)
    for msg in to_messages(inputs, t0=0.0, period=0.5):
        core.on_step(msg) if isinstance(msg, Step) else core.on_feedback(msg)
    core.end()
    live = core.policy_weights()
    for name, w in result.weights.items():
        assert live[name].tobytes() == w.tobytes(), name
    assert core.delay_summary()["oracle"] == result.delay and result.delay["feedbacks"] > 40
