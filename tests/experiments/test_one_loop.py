"""One step loop: the in-process runner and the live learner's core, given the same ordered inputs, end with
the same weights bit for bit, for all four agents."""
import pytest

from common.agents import ALGOS
from common.core.observer import ObserverConfig
from common.protocol import Feedback, Step
from experiments.runner import TrialSpec, run_trials
from common.core.task import Task
from services.common.config import LearnerConfig
from services.learner.core import LearnerCore

RUN = "one-loop"
T0, PERIOD = 1.7e9, 0.01  # wall clock of the live run: step k acts at T0 + k * PERIOD


def runner_inputs(spec: TrialSpec):
    inputs = []
    result = run_trials([spec], on_input=lambda i, kind, rec: inputs.append((kind, rec)))[0]
    return result, inputs


def to_messages(inputs) -> list:
    """The runner's inputs as the actor's Steps and a teacher's Feedback, stamped on a wall clock (a reaction
    at virtual time k + 0.5 is stamped half-way between the wall times of actions k and k + 1)."""
    out, seq_fb, t_in = [], 0, 0
    for kind, rec in inputs:
        if kind == "step":
            k = int(rec["t"])
            out.append(Step(run=RUN, incarnation="actor-1", seq=k, t_action=T0 + k * PERIOD, episode=rec["episode"],
                            t_in_episode=t_in, obs=rec["obs"].tolist(), action=rec["action"], reward=rec["reward"],
                            next_obs=rec["next_obs"].tolist(), terminated=rec["terminated"],
                            truncated=rec["truncated"], weights_version=0, info={}))
            t_in = 0 if rec["terminated"] or rec["truncated"] else t_in + 1
        else:
            out.append(Feedback(run=RUN, teacher_id="oracle", seq=seq_fb, t_reaction=T0 + rec["t"] * PERIOD,
                                value=rec["value"], source="oracle"))
            seq_fb += 1
    return out


@pytest.mark.parametrize("algo", ALGOS)
def test_runner_and_live_learner_end_with_identical_weights(algo):
    config = LearnerConfig(run=RUN, task=Task(env="maze", layout=2, seed=11), algo=algo)
    agent = config.agent
    spec = TrialSpec("maze", agent, ObserverConfig(p_feedback=0.6, delay_probs=(0.3, 0.6, 0.1)), seed=11, layout=2,
                     episodes=8)
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
