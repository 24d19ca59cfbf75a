"""The in-process runner: the core's objects on a virtual clock, many trials stepped in lockstep.

Virtual time: trial i's k-th action is taken at t = k (one unit per step). The observer's reactions land
between steps (see `common.observer.REACTION_OFFSET`) and are delivered, in time order, before the next
action. Per tick (Algorithm 2 of the paper): act, step the env, store the transition, deliver feedback
that has arrived (credit by timestamp, D_local update, or shaping), then the every-b-steps updates.

Trials batched together only share arithmetic: each has its own env, observer, agent state and random
streams, so a trial's actions and returns do not depend on which other trials run beside it.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from common.agents import AgentConfig, TrialBatchAgent
from common.envs import make_env
from common.observer import ObserverConfig, SimulatedObserver
from common.seeding import derive_seed

EPISODE_FIELDS = ("episode", "return", "steps", "feedback_given", "feedback_credited", "feedback_stale",
                  "epsilon", "alpha_h")


@dataclass(frozen=True)
class TrialSpec:
    """One trial: an environment (and layout), an agent, an observer, a seed and a length."""

    env: str
    agent: AgentConfig
    observer: ObserverConfig
    seed: int = 0
    layout: int = 0
    episodes: int = 100


@dataclass
class TrialResult:
    spec: TrialSpec
    episodes: list[dict] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    total_steps: int = 0

    @property
    def returns(self) -> np.ndarray:
        return np.array([e["return"] for e in self.episodes])


def greedy_steps(agent: TrialBatchAgent, i: int, spec: TrialSpec, limit: int = 100) -> int | None:
    """Steps the greedy policy of trial i needs to finish an episode on a fresh copy of its env
    (None if it does not within `limit`). Learning and random streams are untouched."""
    env, _ = make_env(spec.env, spec.layout)
    obs = env.reset(seed=derive_seed(spec.seed, "greedy-eval") % (2**31))[0]
    for k in range(1, limit + 1):
        obs, _, term, trunc, _ = env.step(agent.greedy_action(i, obs))
        if term:
            return k
        if trunc:
            return None
    return None


def run_trials(specs: list[TrialSpec], on_episode: Callable[[int, dict], None] | None = None,
               record_actions: bool = False, greedy_eval: bool = False) -> list[TrialResult]:
    """Run every trial to its episode count; trials must share the environment kind.

    `greedy_eval` adds `greedy_steps` to each episode record: the length of the greedy policy's path
    after that episode (None if it does not reach the goal in 100 steps)."""
    if not specs:
        return []
    torch.set_num_threads(1)  # one thread: the same arithmetic whatever the batch, and room for workers
    B = len(specs)
    envs, observers = [], []
    for s in specs:
        if s.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {s.episodes}")
        env, rule = make_env(s.env, s.layout)
        envs.append(env)
        observers.append(SimulatedObserver(s.observer, rule, derive_seed(s.seed, "observer")))
    obs_dim = envs[0].observation_space.shape[0]
    n_actions = envs[0].action_space.n
    if any(e.observation_space.shape[0] != obs_dim or e.action_space.n != n_actions for e in envs):
        raise ValueError("trials batched together must share observation and action spaces")
    agent = TrialBatchAgent([s.agent for s in specs], obs_dim, n_actions, [s.seed for s in specs])

    results = [TrialResult(s) for s in specs]
    obs = np.zeros((B, obs_dim), np.float32)
    for i, (env, s) in enumerate(zip(envs, specs)):
        obs[i] = env.reset(seed=derive_seed(s.seed, "env") % (2**31))[0]
    active = np.array([s.episodes > 0 for s in specs])
    pending: list[list] = [[] for _ in range(B)]
    event_counter = 0
    episode = np.zeros(B, np.int64)
    ep_return = np.zeros(B)
    ep_steps = np.zeros(B, np.int64)
    ep_given = np.zeros(B, np.int64)
    ep_credited = np.zeros(B, np.int64)
    ep_stale = np.zeros(B, np.int64)

    while active.any():
        actions = agent.act(obs, active)
        ended = []
        for i in np.flatnonzero(active):
            a = int(actions[i])
            t = float(agent.steps[i])  # virtual time of this action
            nxt, r, term, trunc, info = envs[i].step(a)
            agent.record_step(i, obs[i], a, r, nxt, term, t)
            event = observers[i].react(t, info, int(episode[i]), int(t))
            if event is not None:
                event_counter += 1
                heapq.heappush(pending[i], (event.t_reaction, event_counter, event))
            if record_actions:
                results[i].actions.append(a)
            ep_return[i] += r
            ep_steps[i] += 1
            obs[i] = nxt
            if term or trunc:
                ended.append(i)
        # Deliver what arrives before each trial's next action, one event per trial per round.
        due: list[list] = [[] for _ in range(B)]
        for i in np.flatnonzero(active):
            horizon = float(agent.steps[i])  # the next action's time
            while pending[i] and pending[i][0][0] < horizon:
                due[i].append(heapq.heappop(pending[i])[2])
        rounds = max((len(d) for d in due), default=0)
        for r_ in range(rounds):
            batch = [(i, d[r_].t_reaction, d[r_].value) for i, d in enumerate(due) if len(d) > r_]
            for (i, _, _), outcome in zip(batch, agent.give_feedback(batch)):
                ep_given[i] += 1
                ep_credited[i] += outcome.status == "credited"
                ep_stale[i] += outcome.status == "stale"
        agent.update(active)
        for i in ended:
            record = {"episode": int(episode[i]), "return": float(ep_return[i]), "steps": int(ep_steps[i]),
                      "feedback_given": int(ep_given[i]), "feedback_credited": int(ep_credited[i]),
                      "feedback_stale": int(ep_stale[i]),
                      "epsilon": agent.epsilon[i](int(agent.steps[i])),
                      "alpha_h": agent.alpha[i].alpha_h_at(int(agent.steps[i]))}
            if greedy_eval:
                record["greedy_steps"] = greedy_steps(agent, i, specs[i])
            results[i].episodes.append(record)
            if on_episode is not None:
                on_episode(i, record)
            episode[i] += 1
            ep_return[i] = 0.0
            ep_steps[i] = ep_given[i] = ep_credited[i] = ep_stale[i] = 0
            if episode[i] >= specs[i].episodes:
                active[i] = False
                pending[i].clear()
            else:
                obs[i] = envs[i].reset()[0]
    for i, res in enumerate(results):
        res.total_steps = int(agent.steps[i])
    return results
