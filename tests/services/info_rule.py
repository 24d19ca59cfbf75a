"""A user's task for the info tests: a maze whose `info` has a key the project never names, a rule that reads it,
a rule that fails, and an env whose `info` a Step cannot carry (`--env`/`--teacher-rule` as module:function)."""

from __future__ import annotations

from common.envs import MazeEnv


class CheckerMaze(MazeEnv):
    """The project's maze, its cells coloured like a checkerboard; `info["on_dark_square"]` says where it went."""

    def step(self, action: int):
        obs, reward, terminated, truncated, info = super().step(action)
        info["on_dark_square"] = float((int(info["row"]) + int(info["col"])) % 2)
        return obs, reward, terminated, truncated, info


class LabelledMaze(MazeEnv):
    """A maze whose `info` carries a text label: a Step cannot carry it."""

    def step(self, action: int):
        obs, reward, terminated, truncated, info = super().step(action)
        info["label"] = "corridor"
        return obs, reward, terminated, truncated, info


def checker_maze(layout: int = 0) -> CheckerMaze:
    return CheckerMaze(layout)


def labelled_maze(layout: int = 0) -> LabelledMaze:
    return LabelledMaze(layout)


def dark_square_rule(info) -> int:
    """+1 for a step that ends on a dark square, else -1 (reads a key only `CheckerMaze` names)."""
    return 1 if info["on_dark_square"] > 0 else -1


def broken_rule(info) -> int:
    """A rule with a bug: it divides by zero at the first step."""
    return 1 if info["reward"] / 0 > 0 else -1
