"""Environments by name, with the teacher rule that goes with each.

`--env` (every entry point) takes one of:
  * a name registered here (`ENVS`): the paper's `maze`, `maze-pomdp`, `taxi`, and `minigrid-empty`
    (MiniGrid's Empty-5x5 with the three actions it needs: left, right, forward);
  * any Gymnasium id (`FrozenLake-v1`, `CliffWalking-v1`, `MiniGrid-DoorKey-5x5-v0`, ...);
  * `module:factory`, a function returning a discrete-action `gymnasium.Env`, called with `layout=` when
    it takes such a parameter (so `mypkg.envs:make_world` needs no edit of this package).
Environments other than the project's are wrapped in `gym_tasks.TaskEnv` (flat observations, one-hot for
Discrete ones, numeric info with the reward) and, for FrozenLake, CliffWalking and MiniGrid, given the
paper's rule inputs (target distances). The teacher rule is the env's own unless `--teacher-rule` names
one (`common.envs.rules`).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from collections.abc import Callable

import gymnasium as gym

from common.envs.gym_tasks import TaskEnv, minigrid_distance, toy_text_distance
from common.envs.maze import MazeEnv
from common.envs.rules import TeacherRule, auto_rule, checked_rule, load_object, progress_rule, resolve_rule
from common.envs.taxi import TaxiEnv

# Packages whose import registers Gymnasium ids (imported on demand, when an id is not known yet).
GYM_PLUGINS = {"MiniGrid-": "minigrid", "BabyAI-": "minigrid"}
MINIGRID_TURN_FORWARD = (0, 1, 2)  # MiniGrid's left, right, forward


@dataclass(frozen=True)
class EnvSpec:
    name: str
    factory: Callable[..., gym.Env]  # layout -> env
    rule: TeacherRule
    uses_layout: bool


def _gym(env_id: str, actions: tuple[int, ...] | None = None) -> Callable[..., gym.Env]:
    def make(layout: int = 0) -> gym.Env:
        _known_gym_id(env_id)  # imports the package that registers it
        return wrap_gym(gym.make(env_id), env_id, actions)

    return make


ENVS: dict[str, EnvSpec] = {
    "maze": EnvSpec("maze", lambda layout=0: MazeEnv(layout, "mdp"), progress_rule, True),
    "maze-pomdp": EnvSpec("maze-pomdp", lambda layout=0: MazeEnv(layout, "pomdp"), progress_rule, True),
    "taxi": EnvSpec("taxi", lambda layout=0: TaxiEnv(), progress_rule, False),
    "taxi-fixed": EnvSpec("taxi-fixed", lambda layout=0: TaxiEnv(fixed_task=layout), progress_rule, True),
    # The same with the state one-hot appended to the observation (common/envs/taxi.py; the reproduction's).
    "taxi-s": EnvSpec("taxi-s", lambda layout=0: TaxiEnv(state_onehot=True), progress_rule, False),
    "taxi-fixed-s": EnvSpec(
        "taxi-fixed-s", lambda layout=0: TaxiEnv(fixed_task=layout, state_onehot=True), progress_rule, True
    ),
    "minigrid-empty": EnvSpec(
        "minigrid-empty", _gym("MiniGrid-Empty-5x5-v0", MINIGRID_TURN_FORWARD), progress_rule, False
    ),
}
ENV_NAMES = tuple(ENVS)


def wrap_gym(env: gym.Env, name: str, actions: tuple[int, ...] | None = None) -> gym.Env:
    """`env` as the runners need it (`TaskEnv`), with rule inputs where this module knows the world."""
    if isinstance(env, (MazeEnv, TaxiEnv, TaskEnv)):
        return env
    u = env.unwrapped
    distance = minigrid_distance if hasattr(u, "agent_pos") and hasattr(u, "grid") else toy_text_distance(env)
    limit = env.spec.max_episode_steps if env.spec is not None else None
    limit = limit or getattr(u, "max_steps", None)
    return TaskEnv(env, distance, limit, actions, name)


def _known_gym_id(name: str) -> bool:
    if name in gym.registry:
        return True
    for prefix, package in GYM_PLUGINS.items():
        if name.startswith(prefix):
            try:
                __import__(package)
            except ImportError:
                return False
            return name in gym.registry
    return False


def resolve_env(name: str) -> EnvSpec:
    """The spec of `name` (see the module doc); a one-line ValueError naming it when there is none."""
    if name in ENVS:
        return ENVS[name]
    if ":" in name:
        module, _, attr = name.partition(":")
        if module and _known_gym_id(attr) and attr not in ENVS:  # gymnasium's own "module:EnvId" form
            __import__(module)
            return EnvSpec(name, _gym(attr), auto_rule, False)
        factory = load_object(name, "env factory")
        takes_layout = "layout" in _parameters(factory)
        return EnvSpec(
            name, lambda layout=0: _from_factory(factory, name, layout, takes_layout), auto_rule, takes_layout
        )
    if _known_gym_id(name):
        return EnvSpec(name, _gym(name), auto_rule, False)
    raise ValueError(
        f"unknown env {name!r}: not a project env ({', '.join(ENV_NAMES)}), a Gymnasium id, or module:factory"
    )


def _parameters(fn) -> set[str]:
    try:
        return set(inspect.signature(fn).parameters)
    except (TypeError, ValueError):
        return set()


def _from_factory(factory, name: str, layout: int, takes_layout: bool) -> gym.Env:
    try:
        env = factory(layout=layout) if takes_layout else factory()
    except Exception as exc:
        raise ValueError(f"env factory {name!r} failed: {type(exc).__name__}: {exc}") from None
    if not isinstance(env, gym.Env):
        raise ValueError(f"env factory {name!r} returned {type(env).__name__}, not a gymnasium.Env")
    return wrap_gym(env, name)


def make_env(name: str, layout: int = 0, rule: str | None = None) -> tuple[gym.Env, TeacherRule]:
    """The environment `name` and its teacher rule (`rule` names another: `common.envs.rules`)."""
    spec = resolve_env(name)
    chosen = spec.rule if rule is None else resolve_rule(rule)
    return spec.factory(layout), checked_rule(chosen, rule or spec.rule.__name__)


def check_task(env: str, rule: str | None = None) -> None:
    """Raise the one-line ValueError `make_env` would, without building the environment."""
    resolve_env(env)
    if rule is not None:
        resolve_rule(rule)


def n_actions(env: gym.Env) -> int:
    """The number of actions of a discrete-action env (every env the runners make); a ValueError otherwise."""
    space = env.action_space
    if not isinstance(space, gym.spaces.Discrete):
        raise ValueError(f"the agent needs a discrete action space, got {space}")
    return int(space.n)


def obs_shape(env: gym.Env) -> tuple[int, ...]:
    """The shape the network sees (an image's height, width, channels), not the flat vector's."""
    return tuple(getattr(env, "obs_shape", env.observation_space.shape))
