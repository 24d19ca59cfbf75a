"""The paper's 8x8 maze: walls, a start at Manhattan distance 5 from the goal, -0.01 per step, +1 at the goal.

Layouts are generated from fixed seeds (our choice, DESIGN.md), each checked solvable by breadth-first
search and classified for the paper's Manhattan teacher rule (`misleading_dead_ends`):
  honest      an agent taking only the moves the rule approves always reaches the goal (its shortest path
              is then the Manhattan distance);
  misleading  some cell reachable by approved moves alone has no approved move (a dead end along an
              approved path): a teacher who follows the rule leads the agent into it.
Draws come from one stream (seed base + j, j = 0, 1, ...), distinct layouts only; layout L is the
(L // 2)-th honest draw for even L and the (L // 2)-th misleading draw for odd L, so any prefix of the
layouts is balanced. LAYOUT_COUNT = 1,140: 570 of each kind. Layout 0 is the stream's first draw. Layouts 0-59
(the first 30 draws of each kind) are those of every run and pilot before 25 November 2026; layouts 60-119
(the next 30 of each kind, the same stream continued) were fresh for the run declared that day (ae50572);
layouts 120-179 (the stream continued again) are fresh for the run re-declared late on 25 November 2026; layouts
180-659 and 660-1139 (the stream continued, 28 November 2026, before any run used them) are the two runs of the
declaration of 28 November (experiments/claims_2026_11_28.py). Extending the stream changes no earlier layout.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import cache

import gymnasium as gym
import numpy as np

SIZE = 8
START_DISTANCE = 5
MAX_STEPS = 1000
STEP_REWARD = -0.01
GOAL_REWARD = 1.0
WALL_DENSITY = 0.2
LAYOUT_KIND_COUNT = 570
LAYOUT_COUNT = 2 * LAYOUT_KIND_COUNT
HONEST, MISLEADING = "honest", "misleading"
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

    def distances_to_goal(self) -> np.ndarray:
        """[SIZE, SIZE] shortest-path steps from each cell to the goal (-1 for walls and unreachable cells)."""
        dist = np.full((SIZE, SIZE), -1, np.int64)
        dist[self.goal] = 0
        queue = deque([self.goal])
        while queue:
            cell = queue.popleft()
            for dr, dc in MOVES:
                nxt = (cell[0] + dr, cell[1] + dc)
                if not self.is_wall(*nxt) and dist[nxt] < 0:
                    dist[nxt] = dist[cell] + 1
                    queue.append(nxt)
        return dist

    def approved_moves(self, cell: tuple[int, int]) -> list[tuple[int, int]]:
        """Cells the paper's Manhattan rule says +1 to moving into from `cell`: a real move (not into a
        wall) that brings the agent closer to the goal."""
        out = []
        for dr, dc in MOVES:
            nxt = (cell[0] + dr, cell[1] + dc)
            if not self.is_wall(*nxt) and manhattan(nxt, self.goal) < manhattan(cell, self.goal):
                out.append(nxt)
        return out

    def misleading_dead_ends(self) -> list[tuple[int, int]]:
        """Cells other than the goal that an agent taking only approved moves from the start can reach
        and that have no approved move (empty for an honest layout)."""
        seen, queue, dead = {self.start}, deque([self.start]), []
        while queue:
            cell = queue.popleft()
            if cell == self.goal:
                continue
            moves = self.approved_moves(cell)
            if not moves:
                dead.append(cell)
            for nxt in moves:
                if nxt not in seen:
                    seen.add(nxt)
                    queue.append(nxt)
        return sorted(dead)

    @property
    def kind(self) -> str:
        return MISLEADING if self.misleading_dead_ends() else HONEST

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


def _draw(j: int) -> MazeLayout | None:
    """Draw j of the layout stream: random walls, a goal, a start at Manhattan distance 5 (None if the
    walls leave no such start or the goal is unreachable; the stream then moves on to draw j + 1)."""
    rng = np.random.default_rng(_LAYOUT_SEED_BASE + j)
    walls = rng.random((SIZE, SIZE)) < WALL_DENSITY
    free = [(r, c) for r in range(SIZE) for c in range(SIZE) if not walls[r, c]]
    goal = free[rng.integers(len(free))]
    starts = [cell for cell in free if manhattan(cell, goal) == START_DISTANCE]
    if not starts:
        return None
    start = starts[rng.integers(len(starts))]
    layout = MazeLayout(-1, tuple(tuple(bool(w) for w in row) for row in walls), start, goal)
    return layout if layout.shortest_path() is not None else None


class _LayoutStream:
    """The stream of distinct solvable draws, sorted by kind, drawn only as far as a layout asked for needs (all
    1,140 take about 0.3 s, which every process that makes one maze would otherwise pay)."""

    def __init__(self) -> None:
        self.kinds: dict[str, list[MazeLayout]] = {HONEST: [], MISLEADING: []}
        self.seen: set = set()
        self.drawn = {HONEST: 0, MISLEADING: 0}
        self.complete: list[dict[str, int]] = []  # [k]: the draws of each kind when both kinds first held k + 1
        self.j = 0

    def until(self, per_kind: int) -> None:
        while min(len(v) for v in self.kinds.values()) < per_kind:
            layout = _draw(self.j)
            self.j += 1
            if layout is None or (layout.walls, layout.start, layout.goal) in self.seen:
                continue
            self.seen.add((layout.walls, layout.start, layout.goal))
            self.drawn[layout.kind] += 1
            self.kinds[layout.kind].append(layout)
            while len(self.complete) < min(len(v) for v in self.kinds.values()):
                self.complete.append(dict(self.drawn))

    def layout(self, index: int) -> MazeLayout:
        self.until(index // 2 + 1)
        base = self.kinds[layout_kind(index)][index // 2]
        return MazeLayout(index, base.walls, base.start, base.goal)


_STREAM = _LayoutStream()
REPORTED_LAYOUTS = 180
"""The layouts `layout_pool()` gives by default: those of every run to 25 November 2026 (REPORT.md describes them)."""


def layout_pool(count: int = REPORTED_LAYOUTS) -> tuple[tuple[MazeLayout, ...], dict[str, int]]:
    """(the first `count` layouts in index order, how many distinct solvable draws of each kind the stream needed
    for them: the natural frequency of misleading layouts)."""
    if not 0 < count <= LAYOUT_COUNT or count % 2:
        raise ValueError(f"a pool is an even number of layouts in 2..{LAYOUT_COUNT}, got {count}")
    pool = tuple(_STREAM.layout(index) for index in range(count))
    return pool, dict(_STREAM.complete[count // 2 - 1])


def layout_kind(index: int) -> str:
    """honest (even index) or misleading (odd index) for the paper's Manhattan rule."""
    return HONEST if index % 2 == 0 else MISLEADING


@cache
def make_layout(index: int) -> MazeLayout:
    """Layout `index` (0..LAYOUT_COUNT-1): honest for even, misleading for odd indices."""
    if not 0 <= index < LAYOUT_COUNT:
        raise ValueError(f"layout must be in 0..{LAYOUT_COUNT - 1}, got {index}")
    return _STREAM.layout(index)


class MazeEnv(gym.Env):
    """Gymnasium maze. `observation="mdp"`: (row, col) scaled to [0, 1]; `"pomdp"`: the 8 surrounding
    cells, 1.0 for wall (outside the grid counts as wall), 0.0 for space.

    `info` carries what the simulated teacher's rules need: the Manhattan distance to the goal before and
    after the action (`target_distance_before`, `target_distance_after`), the shortest-path distance
    (`path_distance_before`, `path_distance_after`: what a person who knows the maze sees),
    `subgoal_reached` and the step's `reward`.
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
        self._path = self.layout.distances_to_goal()

    def _obs(self) -> np.ndarray:
        r, c = self.pos
        if self.observation == "mdp":
            return np.array([r / (SIZE - 1), c / (SIZE - 1)], dtype=np.float32)
        return np.array(
            [1.0 if self.layout.is_wall(r + dr, c + dc) else 0.0 for dr, dc in NEIGHBOURS], dtype=np.float32
        )

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        self.pos = self.layout.start
        self.steps = 0
        return self._obs(), {"target_distance": float(manhattan(self.pos, self.layout.goal))}

    def step(self, action: int):
        if not 0 <= int(action) < 4:
            raise ValueError(f"maze action must be 0..3, got {action}")
        before = manhattan(self.pos, self.layout.goal)
        path_before = self._path[self.pos]
        dr, dc = MOVES[int(action)]
        nxt = (self.pos[0] + dr, self.pos[1] + dc)
        if not self.layout.is_wall(*nxt):
            self.pos = nxt
        self.steps += 1
        terminated = self.pos == self.layout.goal
        reward = GOAL_REWARD if terminated else STEP_REWARD
        truncated = not terminated and self.steps >= self.max_steps
        after = manhattan(self.pos, self.layout.goal)
        info = {
            "target_distance_before": float(before),
            "target_distance_after": float(after),
            "path_distance_before": float(path_before),
            "path_distance_after": float(self._path[self.pos]),
            "subgoal_reached": 1.0 if terminated else 0.0,
            "reward": float(reward),
            "row": float(self.pos[0]),
            "col": float(self.pos[1]),
        }  # where the agent is (for pictures)
        return self._obs(), reward, terminated, truncated, info

    def render(self):
        return self.layout.ascii(agent=self.pos)
