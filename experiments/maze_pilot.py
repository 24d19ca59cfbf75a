"""`python -m experiments pilot maze`: maze conditions on pilot seeds, long, to choose the maze horizon.

What it is for: choosing how many episodes the reproduction's mazes run (issue 12: "until the best agent's
curve is flat") WITHOUT looking at the trials that decide a verdict. Its trials run layouts
`PILOT_LAYOUTS` (8 honest and 8 misleading; the learned-delay conditions, which run honest layouts only,
use the 8 honest ones, none of which is in their reproduction set) on seeds `PILOT_SEED0 + k`, never a
reproduction trial's seed (`experiments.conditions.trial_seed(layout, rep)`). No claim is computed from it.

For each condition it runs every arm of the condition (so that the cost estimate covers the whole grid,
not only the fast arms), then applies the report's flatness rule (experiments/panels.py `horizon`: the
best arm by its last 10 episodes, the change of its mean ln-steps curve over the last 20 episodes, flat
when below ln 1.1) to the first E episodes, for E = 60, 70, ... up to --episodes. A drifting observer
drifts over --episodes (as the reproduction's drifts over its horizon), so for `delay-drift` only the
last checkpoint is the condition the reproduction would run at that horizon.

    python -m experiments pilot maze --episodes 150 --conditions maze-high-delay,maze-low-delay
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace

import numpy as np

from common.config import option, parse_config
from experiments.conditions import BY_NAME, Condition, agent_for
from experiments.taxi_pilot import PILOT_SEED0

PILOT_LAYOUTS = tuple(range(44, 60))
"""8 honest (even) and 8 misleading (odd) layouts; the learned-delay conditions use the honest ones."""
CHECKPOINTS_FROM = 60
DEFAULT_CONDITIONS = (
    "maze-high-delay",
    "maze-low-nodelay",
    "maze-low-delay",
    "maze-flip",
    "delay-late",
    "delay-long",
    "delay-drift",
)


def pilot_layouts(cond: Condition) -> list[int]:
    return [L for L in PILOT_LAYOUTS if L % 2 == 0] if cond.layouts == "honest" else list(PILOT_LAYOUTS)


def specs(cond: Condition, episodes: int, seed0: int = PILOT_SEED0):
    """Every arm's trials of one condition on the pilot's layouts and seeds (trial k: seed seed0 + k)."""
    from experiments.runner import TrialSpec

    observer = cond.observer
    if observer.late_delay_probs:  # a drifting observer drifts over the whole run
        observer = replace(observer, drift_episodes=episodes)
    out = []
    for arm in cond.arms:
        agent = agent_for(arm, cond.env, cond.true_delay)
        out += [
            (
                arm,
                TrialSpec(
                    cond.env,
                    agent,
                    observer,
                    seed=seed0 + k,
                    layout=L,
                    episodes=episodes,
                    teacher_rule=cond.teacher_rule,
                ),
            )
            for k, L in enumerate(pilot_layouts(cond))
        ]
    return out


def flat_by_episodes(steps_by_arm: dict[str, np.ndarray], stop: int | None) -> list[dict]:
    """The report's horizon rule on the first E episodes, E = 60, 70, ..., all."""
    from experiments.evaluate import ArmData
    from experiments.panels import horizon

    E = next(iter(steps_by_arm.values())).shape[1]
    rows = []
    for e in list(range(CHECKPOINTS_FROM, E, 10)) + [E]:
        arms = {
            arm: ArmData(s[:, :e], -s[:, :e], np.zeros(len(s)), np.arange(len(s)), stop)
            for arm, s in steps_by_arm.items()
        }
        h = horizon(arms, stop)
        rows.append(
            {"episodes": e, "best_arm": h["best_arm"], "change_last": round(h["change_last"], 4), "flat": h["flat"]}
        )
    return rows


def flat_from(rows: list[dict]) -> int | None:
    """The first checkpoint from which every later checkpoint is flat too (None: not flat at the end)."""
    first = None
    for r in rows:
        first = (first or r["episodes"]) if r["flat"] else None
    return first


def run_condition(cond: Condition, episodes: int, seed0: int) -> dict:
    from experiments.runner import run_trials

    labelled = specs(cond, episodes, seed0)
    c0, t0 = time.process_time(), time.perf_counter()
    results = run_trials([s for _, s in labelled])
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    steps: dict[str, list] = {}
    for (arm, _), r in zip(labelled, results):
        steps.setdefault(arm, []).append([e["steps"] for e in r.episodes])
    arrays = {arm: np.array(v, np.float64) for arm, v in steps.items()}
    all_steps = np.concatenate(list(arrays.values()))
    per_episode = all_steps.sum(axis=0)  # environment steps of the whole pilot per episode index
    rows = flat_by_episodes(arrays, cond.stop_episode)
    return {
        "condition": cond.name,
        "trials": len(labelled),
        "arms": list(arrays),
        "cpu_s": cpu,
        "wall_s": wall,
        "env_steps": int(all_steps.sum()),
        "cpu_per_env_step_us": 1e6 * cpu / max(1, all_steps.sum()),
        "steps_first_60_share": float(per_episode[:60].sum() / per_episode.sum()),
        "cumulative_steps": np.cumsum(per_episode).astype(int).tolist(),
        "checkpoints": rows,
        "flat_from": flat_from(rows),
        "curves": {arm: np.log(np.maximum(s, 1)).mean(axis=0).round(4).tolist() for arm, s in arrays.items()},
    }


@dataclass(frozen=True)
class MazePilotConfig:
    """Maze conditions on pilot layouts and seeds, long: the flatness rule at each checkpoint."""

    conditions: tuple[str, ...] = option(
        DEFAULT_CONDITIONS, "maze MDP conditions of experiments/conditions.py (the 7 that were not flat at 60)"
    )
    episodes: int = option(150, "episodes per trial (checkpoints from 60, every 10)")
    seed0: int = option(PILOT_SEED0, f"first pilot seed (>= {PILOT_SEED0})")
    out: str | None = option(None, "write every condition's summary and mean curves as JSON here")

    def __post_init__(self):
        if self.seed0 < PILOT_SEED0:
            raise ValueError(f"seed0 must be >= {PILOT_SEED0}: lower seeds may be the reproduction's")
        bad = [c for c in self.conditions if c not in BY_NAME or BY_NAME[c].is_taxi or BY_NAME[c].env != "maze"]
        if bad:
            raise ValueError(f"not a maze MDP condition: {', '.join(bad)}")
        if self.episodes < CHECKPOINTS_FROM:
            raise ValueError(f"episodes must be >= {CHECKPOINTS_FROM}")


def main(cfg: MazePilotConfig) -> int:
    out = []
    for name in cfg.conditions:
        res = run_condition(BY_NAME[name], cfg.episodes, cfg.seed0)
        out.append(res)
        marks = " ".join(
            f"{r['episodes']}:{r['change_last']:+.3f}{'' if r['flat'] else '*'}" for r in res["checkpoints"]
        )
        print(
            f"{name}: {res['trials']} trials, {res['cpu_s']:.0f} CPU s, {res['env_steps']} steps "
            f"({res['cpu_per_env_step_us']:.1f} us/step), first-60 share of steps {res['steps_first_60_share']:.2f}; "
            f"flat from {res['flat_from']}; change by episodes (* not flat): {marks}",
            flush=True,
        )
    if cfg.out:
        with open(cfg.out, "w") as fh:
            json.dump(out, fh)
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(MazePilotConfig, argv, prog="python -m experiments pilot maze"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments pilot maze")
