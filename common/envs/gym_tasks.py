"""Any discrete-action Gymnasium environment as the runners need it (`TaskEnv`), and the distance
wrappers that give grid worlds the inputs of the paper's teacher rule.

The runners, the replay and the wire all carry an observation as one flat float32 vector, so `TaskEnv`
converts what the environment gives:

  * `Discrete(n)` observations become one-hot vectors of length n (FrozenLake, CliffWalking, Taxi);
  * `Box` observations are flattened; a 3-d `Box` (height, width, channels) is an image: its shape is
    kept in `obs_shape` so that the default network is a CNN (`common.agents.torch_net`), and uint8
    pixels are scaled to [0, 1];
  * a `Dict` with an `image` entry (MiniGrid) is that image (MiniGrid's symbolic 7x7x3 view, each channel
    scaled by its largest value: object, colour, state).

`info` is reduced to its numbers (at most 16, what a Step message carries), with `reward` added, and,
where a distance function is known for the environment, `target_distance_before/after` and
`subgoal_reached` (the teacher-rule contract in `common.envs.rules`). Episodes are cut at `max_steps`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import gymnasium as gym
import numpy as np

MAX_INFO = 16
DEFAULT_MAX_STEPS = 1000
# MiniGrid's symbolic image: object index (<= 10), colour index (<= 5), state (<= 2) per cell.
MINIGRID_SCALE = np.array([10.0, 5.0, 2.0], np.float32)

# (unwrapped env) -> (distance to the current target, sub-goal marker: grows when a sub-goal is reached).
Distance = Callable[[gym.Env], tuple[float, object]]


def _numbers(info: dict) -> dict[str, float]:
    out = {}
    for k, v in info.items():
        if isinstance(v, (bool, int, float, np.integer, np.floating)) and np.isfinite(float(v)):
            out[str(k)] = float(v)
    return dict(list(out.items())[: MAX_INFO - 4])  # room for reward and the rule's inputs


class TaskEnv(gym.Wrapper):
    """A discrete-action env with flat float32 observations, numeric `info` and a step limit.

    `actions`, if given, are the env's actions the agent may take (action k is `actions[k]`)."""

    def __init__(
        self,
        env: gym.Env,
        distance: Distance | None = None,
        max_steps: int | None = None,
        actions: tuple[int, ...] | None = None,
        name: str = "env",
    ):
        super().__init__(env)
        if not isinstance(env.action_space, gym.spaces.Discrete):
            raise ValueError(f"env {name!r}: actions must be Discrete, got {env.action_space}")
        self.name = name
        self.actions = tuple(actions) if actions else tuple(range(int(env.action_space.n)))
        self.action_space = gym.spaces.Discrete(len(self.actions))
        self._convert, self.obs_shape = _converter(env.observation_space, name)
        self.image = len(self.obs_shape) == 3
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (int(np.prod(self.obs_shape)),), np.float32)
        self.distance = distance
        self.max_steps = int(max_steps or DEFAULT_MAX_STEPS)
        self.steps = 0

    def reset(self, *, seed: int | None = None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.steps = 0
        return self._convert(obs), _numbers(info)

    def step(self, action: int):
        action = int(action)
        if not 0 <= action < len(self.actions):
            raise ValueError(f"env {self.name!r}: action must be 0..{len(self.actions) - 1}, got {action}")
        before = self.distance(self.env.unwrapped) if self.distance else None
        obs, reward, terminated, truncated, info = self.env.step(self.actions[action])
        self.steps += 1
        truncated = bool(truncated) or (not terminated and self.steps >= self.max_steps)
        out = _numbers(info)
        out["reward"] = float(reward)
        if before is not None:
            after = self.distance(self.env.unwrapped)
            out["target_distance_before"], out["target_distance_after"] = float(before[0]), float(after[0])
            reached = after[1] > before[1] or (terminated and reward > 0)
            out["subgoal_reached"] = 1.0 if reached else 0.0
        return self._convert(obs), float(reward), bool(terminated), truncated, out


def _converter(space: gym.Space, name: str):
    """(observation -> flat float32 vector, the observation's shape for the network)."""
    if isinstance(space, gym.spaces.Discrete):
        n, start = int(space.n), int(space.start)

        def one_hot(obs):
            v = np.zeros(n, np.float32)
            v[int(obs) - start] = 1.0
            return v

        return one_hot, (n,)
    if isinstance(space, gym.spaces.Dict) and "image" in space.spaces:
        image = space.spaces["image"]
        scale = (
            MINIGRID_SCALE
            if image.shape[-1] == 3 and image.dtype == np.uint8 and image.high.max() == 255 and _is_minigrid(space)
            else _box_scale(image)
        )
        return (lambda obs: (np.asarray(obs["image"], np.float32) / scale).reshape(-1)), tuple(image.shape)
    if isinstance(space, gym.spaces.Box):
        scale = _box_scale(space)
        return (lambda obs: (np.asarray(obs, np.float32) / scale).reshape(-1)), tuple(space.shape)
    raise ValueError(
        f"env {name!r}: observation space {space} is not supported (Discrete, Box, or Dict with an 'image' entry)"
    )


def _is_minigrid(space: gym.spaces.Dict) -> bool:
    return "mission" in space.spaces and "direction" in space.spaces


def _box_scale(space: gym.spaces.Box):
    return np.float32(255.0) if space.dtype == np.uint8 else np.float32(1.0)


# -- distances for grid worlds ----------------------------------------------------------------------------------


def bfs(start, neighbours: Callable, is_target: Callable, limit: int = 100_000) -> float:
    """Fewest moves from `start` to a state where `is_target` holds (inf when none is reachable)."""
    if is_target(start):
        return 0.0
    seen, queue = {start}, deque([(start, 0)])
    while queue and len(seen) < limit:
        state, d = queue.popleft()
        for nxt in neighbours(state):
            if nxt in seen:
                continue
            if is_target(nxt):
                return float(d + 1)
            seen.add(nxt)
            queue.append((nxt, d + 1))
    return float("inf")


def toy_text_distance(env: gym.Env) -> Distance | None:
    """Shortest-path distance to the goal for FrozenLake (around holes) and CliffWalking (around the
    cliff), precomputed per state; None for other environments."""
    unwrapped = env.unwrapped
    if hasattr(unwrapped, "desc") and hasattr(unwrapped, "ncol"):  # FrozenLake
        desc = np.asarray(unwrapped.desc).astype(str)
        blocked, goal = desc == "H", tuple(np.argwhere(desc == "G")[0])
    elif hasattr(unwrapped, "_cliff"):  # CliffWalking
        blocked = np.asarray(unwrapped._cliff, bool)
        goal = (unwrapped.shape[0] - 1, unwrapped.shape[1] - 1)
    else:
        return None
    rows, cols = blocked.shape

    def neighbours(cell):
        r, c = cell
        for dr, dc in ((-1, 0), (0, 1), (1, 0), (0, -1)):
            if 0 <= r + dr < rows and 0 <= c + dc < cols and not blocked[r + dr, c + dc]:
                yield (r + dr, c + dc)

    table = [bfs(divmod(s, cols), neighbours, lambda cell: cell == goal) for s in range(rows * cols)]
    # A hole or the cliff is as far as the grid allows (falling in is never progress).
    table = [d if np.isfinite(d) else float(rows * cols) for d in table]
    return lambda u: (table[int(u.s)], 0)


def minigrid_distance(u) -> tuple[float, object]:
    """Actions (turns and moves) a MiniGrid agent needs to reach its current target: the key while a door
    is locked and no key is carried, then the closed door (to face it), then the goal. The sub-goal
    marker grows when the key is picked up or a door opens."""
    grid, width, height = u.grid, u.width, u.height
    cells = [(x, y, grid.get(x, y)) for x in range(width) for y in range(height)]
    doors = [(x, y) for x, y, o in cells if o is not None and o.type == "door" and not o.is_open]
    keys = [(x, y) for x, y, o in cells if o is not None and o.type == "key"]
    carrying = u.carrying is not None and u.carrying.type == "key"
    locked = any(grid.get(*d).is_locked for d in doors)
    if locked and not carrying and keys:
        targets, face = set(keys), True
    elif doors:
        targets, face = set(doors), True
    else:
        targets, face = {(x, y) for x, y, o in cells if o is not None and o.type == "goal"}, False
    dirs = ((1, 0), (0, 1), (-1, 0), (0, -1))  # MiniGrid's DIR_TO_VEC

    def passable(x, y):
        o = grid.get(x, y)
        return o is None or o.can_overlap()

    def neighbours(state):
        x, y, d = state
        yield (x, y, (d + 1) % 4)
        yield (x, y, (d - 1) % 4)
        nx, ny = x + dirs[d][0], y + dirs[d][1]
        if 0 <= nx < width and 0 <= ny < height and passable(nx, ny):
            yield (nx, ny, d)

    def is_target(state):
        x, y, d = state
        if face:
            return (x + dirs[d][0], y + dirs[d][1]) in targets
        return (x, y) in targets

    start = (int(u.agent_pos[0]), int(u.agent_pos[1]), int(u.agent_dir))
    marker = int(carrying) - 2 * len(doors)
    return min(bfs(start, neighbours, is_target), float(width * height * 4)), marker
