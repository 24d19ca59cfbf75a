"""Teacher rules: what the simulated observer *means* to say about one step, +1 or -1.

The contract of a rule (documented in docs/envs.md): a function `rule(info) -> int` that returns +1 or
-1 and reads only the step's `info`, a mapping of names to floats. What a rule may count on finding:

  * `reward`: the environment's reward for the step (every environment the runners make gives it);
  * `target_distance_before`, `target_distance_after`: the distance (in steps or actions) from the
    agent to its current target before and after the action, where the environment or its wrapper
    provides it (the project's maze and taxi; FrozenLake, CliffWalking and MiniGrid via
    `common.envs.gym_tasks`);
  * `subgoal_reached`: 1.0 when the action completed a sub-goal (goal, pick-up, door opened), else 0.0;
  * whatever else the environment itself puts in `info` (numbers only: `TaskEnv` drops other values; live, the
    actor sends `info` whole and stops with an error naming a key a Step cannot carry).

Rules are named here (`RULES`) or given as `module:function`, so a user's rule needs no package edit.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping

TeacherRule = Callable[[Mapping[str, float]], int]


class RuleError(ValueError):
    """A teacher rule that raised or answered something else than +1/-1; the message names the rule."""


def progress_rule(info: Mapping[str, float]) -> int:
    """The paper's binary rule: +1 if the action brought the agent closer to its current target or
    completed a sub-goal (goal, pick-up, drop-off), else -1."""
    if info.get("subgoal_reached", 0.0) > 0:
        return 1
    return 1 if info["target_distance_after"] < info["target_distance_before"] else -1


def reward_rule(info: Mapping[str, float]) -> int:
    """+1 for a positive reward, else -1 (for environments that give no distance to a target)."""
    return 1 if info.get("reward", 0.0) > 0 else -1


def auto_rule(info: Mapping[str, float]) -> int:
    """`progress` where the step's info has target distances, else `reward`."""
    if "target_distance_after" in info and "target_distance_before" in info:
        return progress_rule(info)
    return reward_rule(info)


def shortest_path_rule(info: Mapping[str, float]) -> int:
    """A teacher who knows the maze: +1 if the action shortened the shortest path to the goal (or reached
    it), else -1 (needs `path_distance_before/after`, which the project's maze provides). Unlike the
    paper's `progress` rule it never leads into a dead end."""
    if info.get("subgoal_reached", 0.0) > 0:
        return 1
    return 1 if info["path_distance_after"] < info["path_distance_before"] else -1


RULES: dict[str, TeacherRule] = {
    "progress": progress_rule,
    "reward": reward_rule,
    "auto": auto_rule,
    "shortest-path": shortest_path_rule,
}


def load_object(spec: str, what: str):
    """`module:name` imported; a ValueError naming `spec` (one line) when it cannot be."""
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ValueError(f"{what} {spec!r}: expected module:name")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # ImportError, or the module's own error at import
        raise ValueError(f"{what} {spec!r}: cannot import {module_name!r} ({type(exc).__name__}: {exc})") from None
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"{what} {spec!r}: {module_name!r} has no {attr!r}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise ValueError(f"{what} {spec!r}: {attr!r} is not callable")
    return obj


def resolve_rule(name: str) -> TeacherRule:
    """A rule by name (`progress`, `reward`, `auto`) or `module:function`."""
    if name in RULES:
        return RULES[name]
    if ":" not in name:
        raise ValueError(f"unknown teacher rule {name!r}; choose one of {', '.join(RULES)} or give module:function")
    return load_object(name, "teacher rule")


def checked_rule(rule: TeacherRule, name: str) -> TeacherRule:
    """`rule`, with its answer checked: anything but +1/-1, or a failure, is a one-line error naming it."""

    def apply(info: Mapping[str, float]) -> int:
        try:
            value = rule(info)
        except Exception as exc:
            raise RuleError(
                f"teacher rule {name!r} failed on info {sorted(info)}: {type(exc).__name__}: {exc}"
            ) from None
        if value not in (1, -1):
            raise RuleError(f"teacher rule {name!r} must return +1 or -1, got {value!r}")
        return int(value)

    apply.__name__ = getattr(rule, "__name__", "rule")
    apply.__doc__ = rule.__doc__
    return apply
