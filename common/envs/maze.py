"""The paper's 8x8 maze: walls, a start at Manhattan distance 5 from the goal, -0.01 per step, +1 at the goal.

Layouts are generated from fixed seeds (our choice, DESIGN.md): layout L is the L-th of ten initial
conditions. Every layout is checked solvable by breadth-first search.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

SIZE = 8
START_DISTANCE = 5
MAX_STEPS = 1000
STEP_REWARD = -0.01
GOAL_REWARD = 1.0
WALL_DENSITY = 0.2
LAYOUT_COUNT = 10
_LAYOUT_SEED_BASE = 20190128  # fixed so that layout L is the same on every machine

# Actions north, east, south, west as (row, col) moves.
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
ACTION_NAMES = ("north", "east", "south", "west")
# Neighbour order of the POMDP observation: row by row around the agent, skipping the agent itself.
NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def manhattan(a: tuple[int, int], b: tuple[int, int]) -> int:
    return abs(a[0] - b[0]) + abs(a[1] - b[1])


@dataclass(frozen=True)
class MazeLayout:
    """Walls (True = wall), start and goal of one maze."""

    index: int
    walls: tuple[tuple[bool, ...], ...]
    start: tuple[int, int]
    goal: tuple[int, int]

    def is_wall(self, r: int, c: int) -> bool:
        return not (0 <= r < SIZE and 0 <= c < SIZE) or self.walls[r][c]

    def shortest_path(self) -> int | None:
        """Length of the shortest start-to-goal path in steps, or None when the goal is unreachable."""
        seen = {self.start: 0}
        queue = deque([self.start])
        while queue:
            cell = queue.popleft()
            if cell == self.goal:
                return seen[cell]
            for dr, dc in MOVES:
                nxt = (cell[0] + dr, cell[1] + dc)
                if not self.is_wall(*nxt) and nxt not in seen:
                    seen[nxt] = seen[cell] + 1
                    queue.append(nxt)
        return None

    def ascii(self, agent: tuple[int, int] | None = None) -> str:
        """'#' wall, '.' space, 'S' start, 'G' goal, 'A' agent."""
        rows = []
        for r in range(SIZE):
            row = []
            for c in range(SIZE):
                if agent == (r, c):
                    row.append("A")
                elif (r, c) == self.goal:
                    row.append("G")
                elif (r, c) == self.start:
                    row.append("S")
                else:
                    row.append("#" if self.walls[r][c] else ".")
            rows.append("".join(row))
        return "\n".join(rows)


def make_layout(index: int) -> MazeLayout:
    """Layout `index` (0..9): random walls from a fixed seed, redrawn until the start can reach the goal."""
    if not 0 <= index < LAYOUT_COUNT:
        raise ValueError(f"layout must be in 0..{LAYOUT_COUNT - 1}, got {index}")
    rng = np.random.default_rng(_LAYOUT_SEED_BASE + index)
    while True:
        walls = rng.random((SIZE, SIZE)) < WALL_DENSITY
        free = [(r, c) for r in range(SIZE) for c in range(SIZE) if not walls[r, c]]
        goal = free[rng.integers(len(free))]
        starts = [cell for cell in free if manhattan(cell, goal) == START_DISTANCE]
        if not starts:
            continue
        start = starts[rng.integers(len(starts))]
        layout = MazeLayout(index, tuple(tuple(bool(w) for w in row) for row in walls), start, goal)
        path = layout.shortest_path()
        # Solvable, and the walls matter at least a little in some layouts: accept any solvable draw.
        if path is not None:
            return layout


class MazeEnv(gym.Env):
    """Gymnasium maze. `observation="mdp"`: (row, col) scaled to [0, 1]; `"pomdp"`: the 8 surrounding
    cells, 1.0 for wall (outside the grid counts as wall), 0.0 for space.

    `info` carries what the simulated teacher's rule needs: the Manhattan distance to the goal before and
    after the action (`target_distance_before`, `target_distance_after`) and `subgoal_reached`.
    """

    metadata = {"render_modes": ["ansi"]}

    def __init__(self, layout: int | MazeLayout = 0, observation: str = "mdp", max_steps: int = MAX_STEPS):
        if observation not in ("mdp", "pomdp"):
            raise ValueError(f"observation must be 'mdp' or 'pomdp', got {observation!r}")
        self.layout = layout if isinstance(layout, MazeLayout) else make_layout(layout)
        self.observation = observation
        self.max_steps = max_steps
        dim = 2 if observation == "mdp" else 8
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(dim,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(4)
        self.pos = self.layout.start
        self.steps = 0

    def _obs(self) -> np.ndarray:
        r, c = self.pos
        if self.observation == "mdp":
            return np.array([r / (SIZE - 1), c / (SIZE - 1)], dtype=np.float32)
        return np.array([1.0 if self.layout.is_wall(r + dr, c + dc) else 0.0 for dr, dc in NEIGHBOURS],
                        dtype=np.float32)

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        self.pos = self.layout.start
        self.steps = 0
        return self._obs(), {"target_distance": float(manhattan(self.pos, self.layout.goal))}

    def step(self, action: int):
        if not 0 <= int(action) < 4:
            raise ValueError(f"maze action must be 0..3, got {action}")
        before = manhattan(self.pos, self.layout.goal)
        dr, dc = MOVES[int(action)]
        nxt = (self.pos[0] + dr, self.pos[1] + dc)
        if not self.layout.is_wall(*nxt):
            self.pos = nxt
        self.steps += 1
        terminated = self.pos == self.layout.goal
        reward = GOAL_REWARD if terminated else STEP_REWARD
        truncated = not terminated and self.steps >= self.max_steps
        after = manhattan(self.pos, self.layout.goal)
        info = {"target_distance_before": float(before), "target_distance_after": float(after),
                "subgoal_reached": 1.0 if terminated else 0.0,
                "row": float(self.pos[0]), "col": float(self.pos[1])}  # where the agent is (for pictures)
        return self._obs(), reward, terminated, truncated, info

    def render(self):
        return self.layout.ascii(agent=self.pos)
