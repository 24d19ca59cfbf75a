"""What a picture of an environment needs, as plain JSON (for the console page; pure, no transport).

`static_scene(env, layout)` describes what never changes (maze walls and goal; taxi walls and stands).
`SceneTracker` turns each Step into where things are now: for the maze it replays the actions from the start
cell (the maze is deterministic, so this works for the POMDP observation too, which hides the position);
the taxi's one-hot observation names its state directly. Other environments get no scene (`None`): the page
then shows the observation numbers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from common.envs.maze import ACTION_NAMES as MAZE_ACTIONS
from common.envs.maze import MOVES, SIZE, make_layout

TAXI_ACTIONS = ("south", "north", "east", "west", "pickup", "dropoff")
TAXI_STANDS = ((0, 0), (0, 4), (4, 0), (4, 3))  # R, G, Y, B (Gymnasium's taxi)


def _taxi_walls() -> list[list[int]]:
    """Walls east of cell (r, c) as [r, c] pairs, read from Gymnasium's map ('|' between two cells)."""
    from gymnasium.envs.toy_text.taxi import MAP

    walls = []
    for r, line in enumerate(MAP[1:-1]):
        for c in range(4):
            if line[2 * c + 2] == "|":
                walls.append([r, c])
    return walls


def static_scene(env: str, layout: int = 0) -> dict[str, Any] | None:
    if env.startswith("maze"):
        lay = make_layout(layout)
        return {
            "kind": "maze",
            "size": SIZE,
            "walls": [[int(w) for w in row] for row in lay.walls],
            "goal": list(lay.goal),
            "start": list(lay.start),
            "actions": list(MAZE_ACTIONS),
        }
    if env.startswith("taxi"):
        return {
            "kind": "taxi",
            "size": 5,
            "stands": [list(s) for s in TAXI_STANDS],
            "stand_names": "RGYB",
            "walls_east": _taxi_walls(),
            "actions": list(TAXI_ACTIONS),
        }
    return None


class SceneTracker:
    """Per-step positions for the page, from the Steps as the actor publishes them."""

    def __init__(self, env: str, layout: int = 0):
        self.kind = env
        self.layout = make_layout(layout) if env.startswith("maze") else None
        self.pos: tuple[int, int] | None = None

    def after(self, t_in_episode: int, action: int, next_obs) -> dict[str, Any] | None:
        """The scene after a step (action taken at position `t_in_episode` of its episode)."""
        if self.layout is not None:
            if t_in_episode == 0 or self.pos is None:
                self.pos = self.layout.start
            dr, dc = MOVES[int(action) % 4]
            nxt = (self.pos[0] + dr, self.pos[1] + dc)
            if not self.layout.is_wall(*nxt):
                self.pos = nxt
            if self.kind == "maze":  # the MDP observation is the position itself: trust it over the replay
                obs = np.asarray(next_obs, np.float64)
                self.pos = (int(round(obs[0] * (SIZE - 1))), int(round(obs[1] * (SIZE - 1))))
            return {"agent": list(self.pos)}
        if self.kind.startswith("taxi"):
            obs = np.asarray(next_obs)
            if obs.shape != (19,):
                return None
            row, col = int(obs[:5].argmax()), int(obs[5:10].argmax())
            return {"taxi": [row, col], "passenger": int(obs[10:15].argmax()), "dest": int(obs[15:19].argmax())}
        return None
