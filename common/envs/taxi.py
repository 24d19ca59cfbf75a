"""Dietterich's taxi (Gymnasium's TaxiEnv) with a 1000-step limit and a one-hot observation.

Observation (our choice, DESIGN.md): one-hot taxi row (5), taxi column (5), passenger location (4 stands
or in the taxi: 5) and destination (4): 19 values. `info` carries the teacher rule's inputs: the Manhattan
distance to the current target (the passenger before pick-up, the destination after) before and after the
action, and `subgoal_reached` for a successful pick-up or drop-off.

`fixed_task=k` (0..11) fixes the passenger's stand and the destination for every episode (the k-th of
the 12 pairs of distinct stands), the taxi's start stays random: one initial condition per k, as the
paper's observation (coordinates and an in-taxi flag) suggests. None (default) is Gymnasium's Taxi:
passenger and destination drawn afresh every episode.

`state_onehot=True` appends a one-hot of Gymnasium's 500 states to the 19 values (519 in all; the first 19
are unchanged, so anything that reads them, e.g. the console's scene, still works). The reproduction's
Taxi uses it: with the 19 factored values alone DQN did not learn Gymnasium's Taxi in 400 episodes
(docs/notes/2026-11-23-reproduction-pilots-and-speed.md "Taxi"), as Q must combine taxi position, passenger and
destination.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.envs.toy_text.taxi import TaxiEnv as _GymTaxi

MAX_STEPS = 1000
OBS_DIM = 5 + 5 + 5 + 4
N_STATES = 500
FIXED_TASKS = tuple((p, d) for p in range(4) for d in range(4) if p != d)


class TaxiEnv(gym.Env):
    metadata = {"render_modes": ["ansi"]}

    def __init__(self, max_steps: int = MAX_STEPS, fixed_task: int | None = None, state_onehot: bool = False):
        if fixed_task is not None and not 0 <= fixed_task < len(FIXED_TASKS):
            raise ValueError(f"fixed_task must be in 0..{len(FIXED_TASKS) - 1}, got {fixed_task}")
        self.fixed_task = fixed_task
        self._env = _GymTaxi()
        self.locs = self._env.locs
        self.max_steps = max_steps
        self.state_onehot = state_onehot
        self.obs_dim = OBS_DIM + (N_STATES if state_onehot else 0)
        # Every observation is this many ones among zeros (row, column, passenger, destination; the state): an agent
        # may keep it as the columns set (common/agents/mlp.py `HotCodes`).
        self.hot_inputs = 4 + (1 if state_onehot else 0)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(self.obs_dim,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(6)
        self.state = 0
        self.steps = 0

    def _decode(self, state: int) -> tuple[int, int, int, int]:
        row, col, passenger, dest = self._env.decode(state)
        return int(row), int(col), int(passenger), int(dest)

    def _obs(self) -> np.ndarray:
        row, col, passenger, dest = self._decode(self.state)
        obs = np.zeros(self.obs_dim, dtype=np.float32)
        obs[row] = 1.0
        obs[5 + col] = 1.0
        obs[10 + passenger] = 1.0
        obs[15 + dest] = 1.0
        if self.state_onehot:
            obs[OBS_DIM + self.state] = 1.0
        return obs

    def _target_distance(self, state: int, target_from: int | None = None) -> int:
        """Distance from the taxi to the target that `target_from`'s passenger state implies."""
        row, col, passenger, dest = self._decode(state)
        ref_passenger = passenger if target_from is None else self._decode(target_from)[2]
        ref_dest = dest
        target = self.locs[ref_dest] if ref_passenger == 4 else self.locs[ref_passenger]
        return abs(row - target[0]) + abs(col - target[1])

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        state, _ = self._env.reset(seed=seed)
        if self.fixed_task is not None:
            row, col, _, _ = self._decode(int(state))
            passenger, dest = FIXED_TASKS[self.fixed_task]
            state = self._env.encode(row, col, passenger, dest)
            self._env.s = int(state)
        self.state = int(state)
        self.steps = 0
        return self._obs(), {"target_distance": float(self._target_distance(self.state))}

    def step(self, action: int):
        if not 0 <= int(action) < 6:
            raise ValueError(f"taxi action must be 0..5, got {action}")
        before_state = self.state
        before = self._target_distance(before_state)
        state, reward, terminated, _, _ = self._env.step(int(action))
        self.state = int(state)
        self.steps += 1
        truncated = not terminated and self.steps >= self.max_steps
        # Distance after the move, to the target that was current before it (a pick-up changes the target).
        after = self._target_distance(self.state, target_from=before_state)
        picked_up = self._decode(before_state)[2] != 4 and self._decode(self.state)[2] == 4
        info = {
            "target_distance_before": float(before),
            "target_distance_after": float(after),
            "subgoal_reached": 1.0 if (picked_up or terminated) else 0.0,
            "reward": float(reward),
        }
        return self._obs(), float(reward), bool(terminated), truncated, info

    def render(self):
        row, col, passenger, dest = self._decode(self.state)
        grid = [["." for _ in range(5)] for _ in range(5)]
        for i, (r, c) in enumerate(self.locs):
            grid[r][c] = "RGYB"[i]
        grid[row][col] = "T" if passenger != 4 else "P"
        return "\n".join("".join(r) for r in grid) + f"\npassenger={'RGYB-'[passenger]} dest={'RGYB'[dest]}"
