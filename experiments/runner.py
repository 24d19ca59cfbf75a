"""The in-process runner: the core's objects on a virtual clock, many trials stepped in lockstep.

Virtual time: trial i's k-th action is taken at t = k (one unit per step). The observer's reactions land
between steps (see `common.observer.REACTION_OFFSET`) and are delivered, in time order, before the next
action. Per tick (Algorithm 2 of the paper): act, step the env, store the transition, deliver feedback
that has arrived (credit by timestamp, D_local update, or shaping), then the every-b-steps updates.

Trials batched together only share arithmetic: each has its own env, observer, agent state and random
streams, so a trial's actions and returns do not depend on which other trials run beside it. Every
per-tick operation is vectorised over the running trials (the agent's row methods, `envbatch` tables, the
observers' pre-drawn uniforms), and finished trials are dropped from the batch (`TrialBatchAgent.select`),
so a batch costs what its running trials cost.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from common.agents import AgentConfig, TrialBatchAgent
from common.agents.agent import CREDITED, STALE
from common.envs import make_env
from common.observer import REACTION_OFFSET, ObserverConfig, SimulatedObserver
from common.seeding import derive_seed
from experiments.envbatch import LoopEnvs, TableEnvs

EPISODE_FIELDS = ("episode", "return", "steps", "feedback_given", "feedback_credited", "feedback_stale",
                  "epsilon", "alpha_h")


def _nz(mask: np.ndarray) -> np.ndarray:
    """Indices of the true entries of a 1-d mask (np.flatnonzero without its overhead)."""
    return mask.nonzero()[0]


@dataclass(frozen=True)
class TrialSpec:
    """One trial: an environment (and layout), an agent, an observer, a seed and a length."""

    env: str
    agent: AgentConfig
    observer: ObserverConfig
    seed: int = 0
    layout: int = 0
    episodes: int = 100
    teacher_rule: str | None = None  # None: the env's own rule (common/envs/rules.py)


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
    """Steps the greedy policy of trial (row) i needs to finish an episode on a fresh copy of its env
    (None if it does not within `limit`). Learning and random streams are untouched."""
    env, _ = make_env(spec.env, spec.layout, spec.teacher_rule)
    obs = env.reset(seed=derive_seed(spec.seed, "greedy-eval") % (2**31))[0]
    for k in range(1, limit + 1):
        obs, _, term, trunc, _ = env.step(agent.greedy_action(i, obs))
        if term:
            return k
        if trunc:
            return None
    return None


class ObserverBatch:
    """`SimulatedObserver.react` for many trials at once.

    Each observer draws three uniforms per step from its own generator (give, lag, flip); here they are
    drawn `block` steps at a time from that same generator (numpy gives the same numbers either way) and
    the observer's rule is applied to arrays: silent after the stop, feedback with probability
    p_feedback, lag by inverse CDF (the same running sum as `DelayModel.sample_steps`), polarity flipped
    with probability p_flip. A test checks it against `SimulatedObserver.react` event for event.
    """

    def __init__(self, observers: list[SimulatedObserver], block: int = 1024):
        self.observers = list(observers)
        self.block = block
        cfgs = [o.config for o in observers]
        big = np.iinfo(np.int64).max
        self.p_feedback = np.array([c.p_feedback for c in cfgs], np.float64)
        self.p_flip = np.array([c.p_flip for c in cfgs], np.float64)
        self.stop_episode = np.array([big if c.stop_episode is None else c.stop_episode for c in cfgs], np.int64)
        self.stop_step = np.array([big if c.stop_step is None else c.stop_step for c in cfgs], np.int64)
        self.n_lags = np.array([len(o.delay.probs) for o in observers], np.int64)
        self.max_lag = int(self.n_lags.max()) - 1
        self.cum = np.zeros((len(observers), self.max_lag + 1), np.float64)
        for k, o in enumerate(observers):
            c = np.cumsum(np.asarray(o.delay.probs, np.float64))
            self.cum[k, :len(c)] = c
            self.cum[k, len(c):] = c[-1]
        self.u = np.zeros((len(observers), block, 3), np.float64)
        self.drawn = np.zeros(len(observers), np.int64)  # steps' worth of uniforms drawn so far

    def react(self, rows: np.ndarray, step: np.ndarray, intended: np.ndarray, episode: np.ndarray):
        """Trials `rows` took their step number `step`: (gives feedback, value, lag in steps)."""
        need = step >= self.drawn[rows]
        for k in rows[need]:
            self.u[k] = self.observers[k].rng.random((self.block, 3))
            self.drawn[k] += self.block
        u = self.u[rows, step % self.block]
        silent = (episode >= self.stop_episode[rows]) | (step >= self.stop_step[rows])
        give = ~silent & (u[:, 0] < self.p_feedback[rows])
        lag = np.minimum((u[:, 1:2] >= self.cum[rows]).sum(axis=1), self.n_lags[rows] - 1)
        value = np.where(u[:, 2] < self.p_flip[rows], -intended, intended)
        return give, value, lag

    def select(self, rows: np.ndarray) -> None:
        for name in ("p_feedback", "p_flip", "stop_episode", "stop_step", "n_lags", "cum", "u", "drawn"):
            setattr(self, name, getattr(self, name)[rows])
        self.observers = [self.observers[k] for k in rows]


def _bucket(n: int) -> str:
    return "1" if n <= 1 else "2-4" if n <= 4 else "5-16" if n <= 16 else "17-64" if n <= 64 else "65+"


def _train_group(agent: AgentConfig) -> int:
    return {(True, False): 0, (True, True): 1, (False, True): 2}.get((agent.train_q, agent.train_h), 3)


def run_trials(specs: list[TrialSpec], on_episode: Callable[[int, dict], None] | None = None,
               record_actions: bool = False, greedy_eval: bool = False,
               on_trial_done: Callable[[int, TrialResult], None] | None = None,
               use_tables: bool = True, profile: dict | None = None) -> list[TrialResult]:
    """Run every trial to its episode count; trials must share observation and action spaces.

    `on_episode(i, record)` is called after each episode of trial i (the index into `specs`),
    `on_trial_done(i, result)` when trial i has run all its episodes. `greedy_eval` adds `greedy_steps`
    to each episode record: the length of the greedy policy's path after that episode (None if it does not
    reach the goal in 100 steps). `use_tables=False` steps the real environments one by one instead of
    the compiled tables (same results, slower; for tests and for environments without tables).
    `profile`, if given, receives per batch-size bucket ("1", "2-4", "5-16", "17-64", "65+" running
    trials) the ticks run and the CPU seconds they took.
    """
    if not specs:
        return []
    torch.set_num_threads(1)  # one thread: the same arithmetic whatever the batch, and room for workers
    assert 0 < REACTION_OFFSET < 1, "delivery below assumes reactions land strictly between two steps"
    B = len(specs)
    for s in specs:
        if s.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {s.episodes}")
    # Rows in the batch are ordered by what the agents train (Q only, Q and H, H only), so the trials
    # due for a Q or an H update are consecutive rows (updated in place, without copies). Results and
    # callbacks use the caller's indices.
    perm = sorted(range(B), key=lambda i: _train_group(specs[i].agent))
    rows_specs = [specs[i] for i in perm]
    envs, rules, keys, observers = [], [], [], []
    for s in rows_specs:
        if s.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {s.episodes}")
        env, rule = make_env(s.env, s.layout, s.teacher_rule)
        envs.append(env)
        rules.append(rule)
        keys.append((s.env, s.layout, s.teacher_rule))
        observers.append(SimulatedObserver(s.observer, rule, derive_seed(s.seed, "observer")))
    obs_dim = envs[0].observation_space.shape[0]
    n_actions = envs[0].action_space.n
    if any(e.observation_space.shape[0] != obs_dim or e.action_space.n != n_actions for e in envs):
        raise ValueError("trials batched together must share observation and action spaces")
    env_seeds = [derive_seed(s.seed, "env") % (2**31) for s in rows_specs]
    EnvBatch = TableEnvs if use_tables and TableEnvs.supports(envs) else LoopEnvs
    world = EnvBatch(envs, rules, keys, env_seeds)
    watchers = ObserverBatch(observers)
    agent = TrialBatchAgent([s.agent for s in rows_specs], obs_dim, n_actions, [s.seed for s in rows_specs])
    results = [TrialResult(s) for s in specs]

    # Per-row state of the running batch (rows are renumbered when finished trials are dropped).
    R = watchers.max_lag + 1  # events in flight arrive within R ticks
    st = {
        "orig": np.array(perm, np.int64),
        "active": np.array([s.episodes > 0 for s in rows_specs]),
        "obs": np.zeros((B, obs_dim), np.float32),
        "episode": np.zeros(B, np.int64),
        "ep_return": np.zeros(B),
        "ep_steps": np.zeros(B, np.int64),
        "ep_given": np.zeros(B, np.int64),
        "ep_credited": np.zeros(B, np.int64),
        "ep_stale": np.zeros(B, np.int64),
        # inbox[row, arrival tick % R, R - 1 - lag]: value of the event from step (arrival - lag), 0 = none;
        # along the last axis events are in the order they were emitted (oldest step first).
        "inbox": np.zeros((B, R, R), np.int64),
    }
    for k in range(B):
        st["obs"][k] = world.reset(k)
    n_episodes = np.array([s.episodes for s in specs], np.int64)
    finished_rows = 0

    tick_start = time.process_time()
    while st["active"].any():
        active = st["active"]
        rows = _nz(active)
        actions = agent.act(st["obs"], active)
        a = actions[rows]
        step = agent.steps[rows].copy()  # this action's virtual time, in steps
        nxt, rew, term, trunc, intended = world.step(rows, a)
        agent.record_steps(rows, st["obs"][rows], a, rew, nxt, term, step.astype(np.float64), st["episode"][rows])
        give, value, lag = watchers.react(rows, step, intended, st["episode"][rows])
        g = _nz(give)
        st["inbox"][rows[g], (step[g] + lag[g]) % R, R - 1 - lag[g]] = value[g]
        if record_actions:
            for i, act in zip(st["orig"][rows], a):
                results[i].actions.append(int(act))
        st["ep_return"][rows] += rew
        st["ep_steps"][rows] += 1
        st["obs"][rows] = nxt
        ended = rows[term | trunc]

        # Deliver what arrives before each trial's next action (at step + REACTION_OFFSET), in emission
        # order, one event per trial per round.
        slot = step % R
        due = st["inbox"][rows, slot]
        st["inbox"][rows, slot] = 0
        has = due != 0
        counts = has.sum(axis=1)
        if counts.any():
            k = _nz(counts > 0)
            order = np.argsort(~has[k], axis=1, kind="stable")
            vals = np.take_along_axis(due[k], order, axis=1)  # each trial's events, oldest step first
            status, _, _ = agent.feedback_rounds(rows[k], step[k].astype(np.float64) + REACTION_OFFSET, vals,
                                                 counts[k])
            rk = rows[k]
            st["ep_given"][rk] += counts[k]
            st["ep_credited"][rk] += np.where(status == CREDITED, counts[k], 0)
            st["ep_stale"][rk] += np.where(status == STALE, counts[k], 0)
        agent.update(active)

        if profile is not None:
            now = time.process_time()
            bucket = profile.setdefault(_bucket(len(rows)), {"ticks": 0, "cpu_s": 0.0, "trial_steps": 0})
            bucket["ticks"] += 1
            bucket["cpu_s"] += now - tick_start
            bucket["trial_steps"] += len(rows)
            tick_start = now
        if len(ended):
            eps_now, alpha_now = agent.epsilons(ended), agent.alpha_h(ended)
            for j, row in enumerate(ended):
                i = int(st["orig"][row])
                record = {"episode": int(st["episode"][row]), "return": float(st["ep_return"][row]),
                          "steps": int(st["ep_steps"][row]), "feedback_given": int(st["ep_given"][row]),
                          "feedback_credited": int(st["ep_credited"][row]),
                          "feedback_stale": int(st["ep_stale"][row]),
                          "epsilon": float(eps_now[j]), "alpha_h": float(alpha_now[j])}
                if greedy_eval:
                    record["greedy_steps"] = greedy_steps(agent, int(row), specs[i])
                results[i].episodes.append(record)
                if on_episode is not None:
                    on_episode(i, record)
                st["episode"][row] += 1
                st["ep_return"][row] = 0.0
                st["ep_steps"][row] = st["ep_given"][row] = st["ep_credited"][row] = st["ep_stale"][row] = 0
                if st["episode"][row] >= n_episodes[i]:
                    st["active"][row] = False
                    st["inbox"][row] = 0
                    results[i].total_steps = int(agent.steps[row])
                    finished_rows += 1
                    if on_trial_done is not None:
                        on_trial_done(i, results[i])
                else:
                    st["obs"][row] = world.reset(int(row))
            # Drop finished trials once they are an eighth of the batch (or the batch is small).
            n_rows = len(st["orig"])
            if finished_rows and finished_rows >= max(1, n_rows // 8) and st["active"].any():
                keep = _nz(st["active"])
                agent.select(keep)
                world.select(keep)
                watchers.select(keep)
                st = {k: v[keep] for k, v in st.items()}
                finished_rows = 0
    for i, s in enumerate(specs):
        if s.episodes == 0 and on_trial_done is not None:
            on_trial_done(i, results[i])
    return results
