"""What a sweep is: a grid over config fields, fixed settings, trials per cell, layouts, named contrasts.

A sweep comes from the command line (`--grid observer.p_feedback=0.1,0.5 agent.algo=dqn,dqn-tamer`), from
a YAML file (same keys, see `docs/sweeps.md`), or both (the command line wins). Every cell of the grid
(one combination of values) runs the same trials: trial k of a cell that does not fix a layout runs
repetition k // L of layout `layouts[k % L]` with a seed derived from both, so with the default layouts
(the reproduction's) trial k is the reproduction's trial k, and every comparison between cells is paired
by trial (same layout and seed).

Field paths (`FIELDS`) are those of `experiments run`'s config tree (`RunConfig`): `env`, `layout`,
`teacher_rule`, `episodes`, `agent.<field>` (with `agent.algo`), `observer.<field>`; values are checked
against the field's type and the config's own validation before anything runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import re
import types
import typing
from dataclasses import dataclass, field
from typing import Any

import yaml

from common.agents import ALGOS, agent_config
from common.envs import LAYOUT_COUNT
from common.envs.registry import resolve_env
from common.core.observer import ObserverConfig
from common.core.task import Task
from experiments.arms import AGENT_OVERRIDES
from experiments.conditions import FULL, MAZE_EPISODES, TAXI_EPISODES, trial_seed
from experiments.run_config import RunConfig
from experiments.runner import TrialSpec


# ------------------------------------------------------------------------------ field paths
@dataclass(frozen=True)
class FieldInfo:
    path: str
    type: Any
    choices: tuple = ()


TRIAL_FIELDS = ("seed",)  # set per trial, not per cell
NOT_SWEPT = ("out",)


def _unwrap(tp) -> tuple[Any, bool]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return args[0], True
    return tp, False


def _tree_fields(cls: type = RunConfig) -> dict[str, FieldInfo]:
    """The paths of `experiments run`'s config tree, as its flags spell them: `env`, `layout`,
    `teacher_rule` (the task, flattened), `episodes`, `agent.<field>`, `observer.<field>`; the agent's
    algorithm is `agent.algo`."""
    out: dict[str, FieldInfo] = {}
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in NOT_SWEPT:
            continue
        base, _ = _unwrap(hints[f.name])
        if not dataclasses.is_dataclass(base):
            out[f.name] = FieldInfo(f.name, hints[f.name], tuple(f.metadata.get("choices", ())))
            continue
        prefix = "" if f.metadata.get("flatten") else f"{f.name}."
        sub = typing.get_type_hints(base)
        for g in dataclasses.fields(base):
            if g.init and g.name not in TRIAL_FIELDS:
                out[prefix + g.name] = FieldInfo(prefix + g.name, sub[g.name], tuple(g.metadata.get("choices", ())))
    out["agent.algo"] = FieldInfo("agent.algo", str, ALGOS)
    out.pop("algo", None)
    return out


FIELDS: dict[str, FieldInfo] = _tree_fields()
"""Every field a sweep can set: the paths of `RunConfig`'s tree (the same names as `experiments run`'s flags)."""

ALIASES = {
    "env.name": "env",
    "env.layout": "layout",
    "env.episodes": "episodes",
    "algo": "agent.algo",
    "observer.flip": "observer.p_flip",
    "rule": "teacher_rule",
}
DEFAULT_EPISODES = {"taxi": TAXI_EPISODES}


def field_path(text: str) -> str:
    """Canonical path of a field name as a user writes it ('observer.p-feedback', 'algo')."""
    path = text.strip().lstrip("-").replace("-", "_")
    path = ALIASES.get(path, path)
    if path not in FIELDS:
        close = [p for p in FIELDS if p.split(".")[-1] == path.split(".")[-1]]
        hint = f"; did you mean {', '.join(close)}?" if close else f"; fields: {', '.join(FIELDS)}"
        raise ValueError(f"unknown sweep field {text!r}{hint}")
    return path


def coerce(path: str, value: Any) -> Any:
    """`value` (from YAML or the command line) as the type of field `path`; ValueError naming it."""
    info = FIELDS[path]
    base, optional = _unwrap(info.type)
    if value is None or (isinstance(value, str) and value.lower() in ("none", "null", "~")):
        if optional:
            return None
        raise ValueError(f"{path} cannot be none")
    try:
        if typing.get_origin(base) is tuple:
            items = value.split(",") if isinstance(value, str) else value
            if not isinstance(items, (list, tuple)):
                raise TypeError
            out = tuple(float(x) for x in items)
        elif base is bool:
            if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "on", "off", "1", "0"):
                value = value.lower() in ("true", "yes", "on", "1")
            if not isinstance(value, bool):
                raise TypeError
            out = value
        elif base is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise TypeError
            out = int(value)
        elif base is float:
            if isinstance(value, bool):
                raise TypeError
            out = float(value)
        else:
            out = str(value)
    except (TypeError, ValueError):
        raise ValueError(f"{path} expects {getattr(base, '__name__', base)}, got {value!r}") from None
    if info.choices and out not in info.choices:
        raise ValueError(f"{path} must be one of {', '.join(info.choices)}, got {out!r}")
    return out


def split_top(text: str) -> list[str]:
    """Split at commas that are not inside brackets: 'a,[1,0],b' -> ['a', '[1,0]', 'b']."""
    parts, depth, cur = [], 0, ""
    for ch in text:
        depth += ch in "[("
        depth -= ch in "])"
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    return parts + [cur]


def parse_values(path: str, text: str) -> list:
    values = []
    for part in split_top(text):
        part = part.strip()
        if not part:
            raise ValueError(f"{path}: empty value in {text!r}")
        try:
            loaded = yaml.safe_load(part)
        except yaml.YAMLError:
            loaded = part
        values.append(coerce(path, loaded))
    return values


def parse_assignment(text: str) -> tuple[str, str]:
    if "=" not in text:
        raise ValueError(f"expected FIELD=VALUE[,VALUE...], got {text!r}")
    name, _, rhs = text.partition("=")
    return field_path(name), rhs


def fmt_value(v: Any) -> str:
    """A value as it appears in names, titles and legends."""
    if isinstance(v, tuple):
        return "[" + ",".join(f"{x:g}" for x in v) + "]"
    if isinstance(v, float):
        return f"{v:g}"
    return "none" if v is None else str(v)


# ------------------------------------------------------------------------------------ sweeps
@dataclass(frozen=True)
class Cell:
    index: int
    values: dict  # swept path -> value, in grid order

    @property
    def label(self) -> str:
        return ", ".join(f"{p}={fmt_value(v)}" for p, v in self.values.items()) or "all"

    @property
    def slug(self) -> str:
        """A file-name-safe id: index plus a readable, shortened label."""
        text = "_".join(f"{p.split('.')[-1]}-{fmt_value(v)}" for p, v in self.values.items()) or "all"
        return f"c{self.index:03d}-" + re.sub(r"[^A-Za-z0-9._-]+", "", text)[:60]


@dataclass
class Sweep:
    name: str = "sweep"
    grid: dict[str, list] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)
    trials: int = 10
    layouts: tuple[int, ...] | None = None
    contrasts: list[str] = field(default_factory=list)
    legend: str | None = None

    def __post_init__(self):
        self.grid = {field_path(p): [coerce(field_path(p), v) for v in vs] for p, vs in self.grid.items()}
        self.fixed = {field_path(p): coerce(field_path(p), v) for p, v in self.fixed.items()}
        if self.trials < 2:
            raise ValueError(f"trials must be at least 2 (intervals need resampling), got {self.trials}")
        overlap = set(self.grid) & set(self.fixed)
        if overlap:
            raise ValueError(f"{', '.join(sorted(overlap))} both swept and fixed")
        for path, values in self.grid.items():
            if not values:
                raise ValueError(f"{path}: no values")
            if len({json.dumps(v) for v in values}) != len(values):
                raise ValueError(f"{path}: repeated values {values}")
        if self.layouts is not None:
            bad = [x for x in self.layouts if not 0 <= x < LAYOUT_COUNT]
            if bad or not self.layouts:
                raise ValueError(f"layouts must be in 0..{LAYOUT_COUNT - 1}, got {list(self.layouts)}")
        if self.legend is not None:
            self.legend = field_path(self.legend)
            if self.legend not in self.grid:
                raise ValueError(f"legend field {self.legend} is not swept")
        for cell in self.cells():  # every cell must make a valid config before anything runs
            try:
                self.spec(cell, 0)
            except ValueError as exc:
                raise ValueError(f"cell {cell.label}: {exc}") from None

    def cells(self) -> list[Cell]:
        paths = list(self.grid)
        return [
            Cell(i, dict(zip(paths, combo)))
            for i, combo in enumerate(itertools.product(*(self.grid[p] for p in paths)))
        ]

    def settings(self, cell: Cell) -> dict[str, Any]:
        return {"env": "maze", **self.fixed, **cell.values}

    def layout_seed(self, settings: dict, k: int) -> tuple[int, int]:
        """(layout, seed) of trial k, the reproduction's trial plan: repetition k // L of layout
        layouts[k % L], seeded from both (`conditions.trial_seed`); a fixed layout repeats it, and an
        environment without layouts has layout 0. By default the development layouts 0-59 and seed block 1:
        a sweep never runs the reproduction's deciding trials (layouts 60-179, blocks 2 and 3)."""
        if settings.get("layout") is not None:
            layout, rep = settings["layout"], k
        elif not resolve_env(settings["env"]).uses_layout:
            layout, rep = 0, k
        else:
            layouts = self.layouts or tuple(range(FULL.layouts))
            layout, rep = layouts[k % len(layouts)], k // len(layouts)
        return layout, trial_seed(layout, rep)

    def spec(self, cell: Cell, k: int) -> TrialSpec:
        s = self.settings(cell)
        env = s["env"]
        layout, seed = self.layout_seed(s, k)
        task = Task(env=env, layout=layout, seed=seed, teacher_rule=s.get("teacher_rule"))  # validates them
        agent_kw = {p.split(".", 1)[1]: v for p, v in s.items() if p.startswith("agent.")}
        algo = agent_kw.pop("algo", "dqn-tamer")
        agent = agent_config(algo, **{**AGENT_OVERRIDES.get(env, {}), **agent_kw})
        observer = ObserverConfig(**{p.split(".", 1)[1]: v for p, v in s.items() if p.startswith("observer.")})
        episodes = s.get("episodes")
        episodes = DEFAULT_EPISODES.get(env, MAZE_EPISODES) if episodes is None else episodes
        if episodes < 1:
            raise ValueError(f"episodes must be positive, got {episodes}")
        return TrialSpec(
            task.env,
            agent,
            observer,
            seed=task.seed,
            layout=task.layout,
            episodes=episodes,
            teacher_rule=task.teacher_rule,
        )

    def record(self) -> dict:
        """The sweep as YAML/JSON-able data (what `from_mapping` reads back)."""
        plain = lambda v: list(v) if isinstance(v, tuple) else v  # noqa: E731
        return {
            "name": self.name,
            "trials": self.trials,
            "layouts": None if self.layouts is None else list(self.layouts),
            "set": {p: plain(v) for p, v in self.fixed.items()},
            "grid": {p: [plain(v) for v in vs] for p, vs in self.grid.items()},
            "contrasts": list(self.contrasts),
            "legend": self.legend,
        }

    def digest(self) -> str:
        return hashlib.sha1(json.dumps(self.record(), sort_keys=True).encode()).hexdigest()[:12]


def from_mapping(data: dict, source: str = "sweep file") -> dict:
    """Keyword arguments of `Sweep` from a YAML/JSON mapping (unknown keys are errors)."""
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a mapping with grid:, set:, trials: ...")
    known = {"name", "trials", "layouts", "set", "grid", "contrasts", "legend"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{source}: unknown keys {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    kw: dict[str, Any] = {k: data[k] for k in ("name", "trials", "legend") if data.get(k) is not None}
    if data.get("layouts") is not None:
        kw["layouts"] = tuple(coerce("layout", x) for x in _as_list(data["layouts"], "layouts"))
    grid = data.get("grid") or {}
    fixed = data.get("set") or {}
    if not isinstance(grid, dict) or not isinstance(fixed, dict):
        raise ValueError(f"{source}: grid: and set: must be mappings of field paths")
    kw["grid"] = {}
    for name, values in grid.items():
        path = field_path(name)
        vals = (
            parse_values(path, values) if isinstance(values, str) else [coerce(path, v) for v in _as_list(values, path)]
        )
        kw["grid"][path] = vals
    kw["fixed"] = {field_path(name): coerce(field_path(name), v) for name, v in fixed.items()}
    kw["contrasts"] = [str(c) for c in _as_list(data.get("contrasts") or [], "contrasts")]
    return kw


def _as_list(v, what: str) -> list:
    if not isinstance(v, (list, tuple)):
        raise ValueError(f"{what}: expected a list, got {v!r}")
    return list(v)


def load_yaml(path: str) -> dict:
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    return from_mapping(data or {}, path)
