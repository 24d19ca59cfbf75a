"""Batching must not change the science: a trial gives the same actions and returns whatever runs beside
it, whether its environment is stepped by tables or for real, and the vectorised pieces agree with the
plain ones they replace."""

import numpy as np
import pytest

from common.agents import TrialBatchAgent, agent_config
from common.core.credit import credit_weights
from common.core.delay import DelayModel
from common.envs import progress_rule
from common.core.observer import ObserverConfig, SimulatedObserver
from common.core.observer import ObserverBatch
from experiments.runner import TrialSpec, run_trials

ALGOS = ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer")
DELAYED = ObserverConfig(p_feedback=0.5, delay_probs=(0.3, 0.6, 0.1))


def mixed_specs(env="maze"):
    """All four agents, several layouts, observers and lengths, so trials finish at different times and
    the batch is shrunk while others still run."""
    observers = [
        DELAYED,
        ObserverConfig(p_feedback=0.1, delay_probs=(1.0,)),
        ObserverConfig(p_feedback=0.5, p_flip=0.15, stop_episode=2),
    ]
    return [
        TrialSpec(env, agent_config(algo), observers[k % 3], seed=k, layout=k % 10, episodes=2 + k % 4)
        for k, algo in enumerate(ALGOS * 3)
    ]


@pytest.mark.parametrize("env", ["maze", "taxi"])
def test_a_trial_batched_acts_and_returns_as_it_does_alone(env):
    specs = mixed_specs(env)
    if env == "taxi":
        specs = [TrialSpec(s.env, s.agent, s.observer, s.seed, 0, 1 + s.episodes // 3) for s in specs[:6]]
    batched = run_trials(specs, record_actions=True)
    for spec, res in zip(specs, batched):
        alone = run_trials([spec], record_actions=True)[0]
        assert len(res.actions) == res.total_steps > 0
        assert res.actions == alone.actions, spec
        np.testing.assert_array_equal(res.returns, alone.returns)
        assert res.episodes == alone.episodes


@pytest.mark.parametrize("env", ["maze", "maze-pomdp", "taxi"])
def test_compiled_tables_step_exactly_like_the_real_environments(env):
    specs = [TrialSpec(env, agent_config(a), DELAYED, seed=7, layout=3, episodes=2) for a in ("dqn", "dqn-tamer")]
    tabled = run_trials(specs, record_actions=True)
    looped = run_trials(specs, record_actions=True, use_tables=False)
    for a, b in zip(tabled, looped):
        assert a.actions == b.actions
        assert a.episodes == b.episodes


def test_observer_batch_reacts_as_single_observers_do_event_for_event():
    cfgs = [
        ObserverConfig(0.5, (0.3, 0.6, 0.1), 0.15, None, None),
        ObserverConfig(0.1, (1.0,)),
        ObserverConfig(1.0, (0.2, 0.2, 0.2, 0.4), 0.5, stop_episode=3),
        ObserverConfig(0.7, stop_step=2500),
    ]
    ref = [SimulatedObserver(c, progress_rule, seed=11 + k) for k, c in enumerate(cfgs)]
    batch = ObserverBatch(cfgs, [11 + k for k in range(len(cfgs))], block=64)
    rng = np.random.default_rng(0)
    rows = np.arange(len(cfgs))
    for step in range(3000):
        intended = rng.choice([-1, 1], size=len(cfgs))
        episode = np.full(len(cfgs), step // 500)
        give, value, lag = batch.react(rows, intended, episode, np.full(len(cfgs), step))
        for k, o in enumerate(ref):
            info = {"target_distance_before": 2.0, "target_distance_after": 1.0 if intended[k] > 0 else 3.0}
            ev = o.react(float(step), info, int(episode[k]), step)
            assert give[k] == (ev is not None)
            if ev is not None:
                assert (value[k], lag[k]) == (ev.value, ev.lag_steps)


def test_agent_history_credits_with_the_credit_function():
    rng = np.random.default_rng(3)
    model = DelayModel((0.2, 0.5, 0.0, 0.3), unit=0.7)
    agent = TrialBatchAgent(
        [agent_config("dqn-tamer", assumed_delay_probs=model.probs, history_steps=6)] * 4,
        2,
        4,
        [0, 1, 2, 3],
        step_unit=0.7,
    )
    times = [[] for _ in range(4)]
    for k in range(40):
        rows = np.flatnonzero(rng.random(4) < 0.8)
        t = np.array([(times[i][-1] if times[i] else 0.0) + rng.exponential(0.6) for i in rows])
        agent.record_steps(
            rows,
            rng.random((len(rows), 2)),
            rng.integers(0, 4, len(rows)),
            np.zeros(len(rows)),
            rng.random((len(rows), 2)),
            np.zeros(len(rows)),
            t,
            np.full(len(rows), k // 10),
        )
        for i, ti in zip(rows, t):
            times[i].append(ti)
        t_f = np.array([(times[i][-1] if times[i] else 0.0) + rng.uniform(-1, 3) for i in range(4)])
        got = agent.history.credit(np.arange(4), t_f, agent.delays.step_delay(np.arange(4)), agent.local_width)
        for i in range(4):
            w, lost = credit_weights(t_f[i], times[i][-6:], model)
            nz = w[w > 0]
            assert got.counts[i] == len(nz)
            np.testing.assert_array_equal(got.weights[i, : len(nz)], nz)
            assert got.lost[i] == pytest.approx(lost)


def test_state_dict_round_trip_continues_the_same_trial():
    spec_cfg = [agent_config("dqn-tamer"), agent_config("dqn-rs")]
    rng = np.random.default_rng(1)

    def drive(agent, steps, start):
        acts = []
        for k in range(start, start + steps):
            obs = rng_obs[k]
            a = agent.act(obs)
            agent.record_steps(
                np.arange(2), obs, a, np.full(2, -0.01), rng_obs[k + 1], np.zeros(2), np.full(2, float(k)), np.zeros(2)
            )
            agent.feedback_rounds(
                np.arange(2), np.full(2, k + 0.5), np.where(a % 2 == 0, 1, -1)[:, None], np.ones(2, np.int64)
            )
            agent.update()
            acts.append(a.copy())
        return acts

    rng_obs = rng.random((202, 2, 2)).astype(np.float32)
    full = TrialBatchAgent(spec_cfg, 2, 4, [5, 6])
    reference = drive(full, 200, 0)
    first = TrialBatchAgent(spec_cfg, 2, 4, [5, 6])
    drive(first, 120, 0)
    second = TrialBatchAgent(spec_cfg, 2, 4, [5, 6])
    second.load_state_dict(first.state_dict())
    rest = drive(second, 80, 120)
    assert all(np.array_equal(a, b) for a, b in zip(reference[120:], rest))
