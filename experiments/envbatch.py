"""Many environments stepped as one: lookup tables compiled from the real environments, or a plain loop.

The paper's environments are small and deterministic (Maze: 64 cells x 4 actions; Taxi: 500 states x 6
actions), so every trial's environment can be stepped at once by indexing tables. The tables are not a
second implementation: they are filled by calling the real environment's own `step` from every state
(`compile_table`), and the teacher rule is applied to the real `info`, so the rules live in one place.
An environment without a table adapter is stepped in a Python loop (`LoopEnvs`); both give the same
transitions, and a test checks that tabled trials equal looped ones step for step.

Reset goes through the real environment every time, so random start states (Taxi) come from the
environment's own generator. Gymnasium's Taxi draws one uniform from that generator on every `step`
(its `categorical_sample`, even though its transitions are deterministic); the Taxi adapter replays
those draws before each reset so the start states are those a real stepped Taxi would give.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

from common.envs import MazeEnv, TaxiEnv
from common.envs.maze import SIZE


@dataclass
class EnvTable:
    obs: np.ndarray  # [S, obs_dim] float32
    next_state: np.ndarray  # [S, A] int64
    reward: np.ndarray  # [S, A] float64
    terminated: np.ndarray  # [S, A] bool
    feedback: np.ndarray  # [S, A] int64: the teacher rule's +1/-1 for that step
    max_steps: int


class _MazeAdapter:
    n_states = SIZE * SIZE

    @staticmethod
    def get(env: MazeEnv) -> int:
        return env.pos[0] * SIZE + env.pos[1]

    @staticmethod
    def set(env: MazeEnv, s: int) -> None:
        env.pos = (s // SIZE, s % SIZE)
        env.steps = 0

    @staticmethod
    def obs(env: MazeEnv) -> np.ndarray:
        return env._obs()

    @staticmethod
    def before_reset(env: MazeEnv, steps_since_reset: int) -> None:
        pass

    @staticmethod
    def rng_state(env):
        return None

    @staticmethod
    def restore_rng(env, state) -> None:
        pass


class _TaxiAdapter:
    n_states = 500

    @staticmethod
    def get(env: TaxiEnv) -> int:
        return int(env.state)

    @staticmethod
    def set(env: TaxiEnv, s: int) -> None:
        env.state = s
        env._env.s = s
        env.steps = 0

    @staticmethod
    def obs(env: TaxiEnv) -> np.ndarray:
        return env._obs()

    @staticmethod
    def before_reset(env: TaxiEnv, steps_since_reset: int) -> None:
        if steps_since_reset:
            env._env.np_random.random(steps_since_reset)  # the draws gymnasium's step would have made

    @staticmethod
    def rng_state(env: TaxiEnv):
        return env._env.np_random.bit_generator.state

    @staticmethod
    def restore_rng(env: TaxiEnv, state) -> None:
        env._env.np_random.bit_generator.state = state


ADAPTERS = {MazeEnv: _MazeAdapter, TaxiEnv: _TaxiAdapter}


def compile_table(env, rule: Callable) -> EnvTable:
    """Call env.step(a) from every state s and record what happens (the env's own code is the model)."""
    ad = ADAPTERS[type(env)]
    saved = ad.rng_state(env)
    S, A = ad.n_states, env.action_space.n
    obs = np.zeros((S, env.observation_space.shape[0]), np.float32)
    nxt = np.zeros((S, A), np.int64)
    rew = np.zeros((S, A), np.float64)
    term = np.zeros((S, A), bool)
    fb = np.zeros((S, A), np.int64)
    for s in range(S):
        ad.set(env, s)
        obs[s] = ad.obs(env)
        for a in range(A):
            ad.set(env, s)
            _, r, te, _, info = env.step(a)
            nxt[s, a], rew[s, a], term[s, a], fb[s, a] = ad.get(env), r, te, rule(info)
    ad.restore_rng(env, saved)
    return EnvTable(obs, nxt, rew, term, fb, int(env.max_steps))


_TABLE_CACHE: dict = {}


class TableEnvs:
    """B trials' environments stepped by table lookup (one table per distinct env name and layout)."""

    def __init__(self, envs: list, rules: list, keys: list, seeds: list[int]):
        tables, self.table_id = [], np.zeros(len(envs), np.int64)
        index = {}
        for k, (env, rule, key) in enumerate(zip(envs, rules, keys)):
            if key not in index:
                if key not in _TABLE_CACHE:
                    _TABLE_CACHE[key] = compile_table(env, rule)
                index[key] = len(tables)
                tables.append(_TABLE_CACHE[key])
            self.table_id[k] = index[key]
        self.obs_t = np.stack([t.obs for t in tables])
        self.next_t = np.stack([t.next_state for t in tables])
        self.rew_t = np.stack([t.reward for t in tables])
        self.term_t = np.stack([t.terminated for t in tables])
        self.fb_t = np.stack([t.feedback for t in tables])
        self.max_steps = np.array([tables[i].max_steps for i in self.table_id], np.int64)
        self.envs = list(envs)
        self.adapters = [ADAPTERS[type(e)] for e in envs]
        self.state = np.zeros(len(envs), np.int64)
        self.ep_steps = np.zeros(len(envs), np.int64)
        self.first = [True] * len(envs)
        self.seeds = list(seeds)

    @staticmethod
    def supports(envs: list) -> bool:
        return all(type(e) in ADAPTERS for e in envs)

    def reset(self, row: int) -> np.ndarray:
        env, ad = self.envs[row], self.adapters[row]
        if self.first[row]:
            env.reset(seed=self.seeds[row])
            self.first[row] = False
        else:
            ad.before_reset(env, int(self.ep_steps[row]))
            env.reset()
        self.state[row] = ad.get(env)
        self.ep_steps[row] = 0
        return self.obs_t[self.table_id[row], self.state[row]]

    def step(self, rows: np.ndarray, actions: np.ndarray):
        tid, s = self.table_id[rows], self.state[rows]
        ns = self.next_t[tid, s, actions]
        self.state[rows] = ns
        self.ep_steps[rows] += 1
        term = self.term_t[tid, s, actions]
        trunc = ~term & (self.ep_steps[rows] >= self.max_steps[rows])
        return self.obs_t[tid, ns], self.rew_t[tid, s, actions], term, trunc, self.fb_t[tid, s, actions]

    def select(self, rows: np.ndarray) -> None:
        for name in ("table_id", "max_steps", "state", "ep_steps"):
            setattr(self, name, getattr(self, name)[rows])
        for name in ("envs", "adapters", "first", "seeds"):
            setattr(self, name, [getattr(self, name)[k] for k in rows])


class LoopEnvs:
    """The same interface over real environments stepped one by one (any Gymnasium env with a rule)."""

    def __init__(self, envs: list, rules: list, keys: list, seeds: list[int]):
        self.envs, self.rules, self.seeds = list(envs), list(rules), list(seeds)
        self.first = [True] * len(envs)

    def reset(self, row: int) -> np.ndarray:
        if self.first[row]:
            self.first[row] = False
            return self.envs[row].reset(seed=self.seeds[row])[0]
        return self.envs[row].reset()[0]

    def step(self, rows: np.ndarray, actions: np.ndarray):
        n = len(rows)
        obs = np.zeros((n, self.envs[0].observation_space.shape[0]), np.float32)
        rew, term, trunc = np.zeros(n), np.zeros(n, bool), np.zeros(n, bool)
        fb = np.zeros(n, np.int64)
        for k, (i, a) in enumerate(zip(rows, actions)):
            obs[k], rew[k], term[k], trunc[k], info = self.envs[i].step(int(a))
            fb[k] = self.rules[i](info)
        return obs, rew, term, trunc, fb

    def select(self, rows: np.ndarray) -> None:
        for name in ("envs", "rules", "seeds", "first"):
            setattr(self, name, [getattr(self, name)[k] for k in rows])
