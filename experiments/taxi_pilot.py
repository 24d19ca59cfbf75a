"""`python -m experiments pilot taxi`: DQN alone on Taxi, on pilot seeds, until it converges (or not).

What it is for: choosing the reproduction's Taxi horizon and settings WITHOUT looking at the trials that
decide a verdict. The pilot's seeds (`PILOT_SEED0 + k`) are never the reproduction's (those are
`experiments.conditions.trial_seed(layout, rep)`, and its fixed-task trials run the 12 tasks in order),
and it runs DQN only: no claim is computed from it. It also measures how many episodes and environment
steps DQN needs to converge on Taxi, whatever the reproduction's budget
(docs/notes/2026-11-23-reproduction-pilots-and-speed.md "Taxi").

Convergence, the reproduction's rule (experiments/panels.py `horizon`): the mean ln-steps curve over the
trials is flat over its last 20 episodes (change below ln 1.1) and its last 10 episodes' geometric mean
is below 100 steps; the episode of convergence is the first at which the 5-episode moving average comes
within ln 1.1 of the final level. Per trial it also prints the first episode from which the 10-episode
median stays below 100 steps.

    python -m experiments pilot taxi --env taxi-s --episodes 300 --trials 3 --set replay_size=50000
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass

import numpy as np

from common.config import option, parse_config

from experiments.arms import AGENT_OVERRIDES
from experiments.panels import CONVERGED_STEPS

PILOT_SEED0 = 9000
"""Pilot seeds are 9000, 9001, ...: never a reproduction trial's seed (those come from trial_seed)."""


def _value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def specs(env: str, episodes: int, trials: int, changes: dict, seed0: int = PILOT_SEED0):
    from common.agents import agent_config
    from common.core.observer import ObserverConfig
    from experiments.runner import TrialSpec

    agent = agent_config("dqn", **{**AGENT_OVERRIDES.get(env, {}), **changes})
    # fixed task: pilot k runs task (k * 5 + 3) % 12, a different order from the reproduction's 0, 1, 2, ...
    layouts = [(k * 5 + 3) % 12 if env.startswith("taxi-fixed") else 0 for k in range(trials)]
    return [
        TrialSpec(env, agent, ObserverConfig(), seed=seed0 + k, layout=layouts[k], episodes=episodes)
        for k in range(trials)
    ]


def convergence(steps: np.ndarray) -> dict:
    """The reproduction's convergence rule (experiments/panels.py `horizon`, the same function the report uses) on
    a [trials, episodes] array of DQN's episode lengths, and per trial the first episode from which the 10-episode
    median stays below CONVERGED_STEPS."""
    from experiments.evaluate import ArmData
    from experiments.panels import horizon

    n, E = steps.shape
    h = horizon({"dqn": ArmData(steps, -steps, np.zeros(n), np.arange(n), None, taxi=True)}, None)
    per_trial = []
    for row in steps:
        med = np.array([np.median(row[max(0, e - 9) : e + 1]) for e in range(E)])
        bad = np.nonzero(med >= CONVERGED_STEPS)[0]
        first = 0 if not len(bad) else int(bad[-1] + 1)
        per_trial.append(first + 1 if first < E else None)
    return {
        "episodes": E,
        "change_last": h["dqn_change_last"],
        "flat": h["dqn_flat"],
        "final_steps_geomean": h["dqn_final_steps_geomean"],
        "converged": h["dqn_converged"],
        "within_margin_episode": h["dqn_within_margin_episode"],
        "steps_to_level_mean": h["dqn_steps_to_level_mean"],
        "steps_total_mean": h["dqn_steps_total_mean"],
        "trial_median_below_100_from_episode": per_trial,
    }


@dataclass(frozen=True)
class TaxiPilotConfig:
    """DQN alone on Taxi, on pilot seeds: the report's convergence rule, to choose the Taxi horizon."""

    env: str = option(
        "taxi-s",
        "taxi-s (Gymnasium's, one-hot), taxi-fixed-s, taxi, taxi-fixed",
        choices=("taxi-s", "taxi-fixed-s", "taxi", "taxi-fixed"),
    )
    episodes: int = option(300, "episodes per trial")
    trials: int = option(3, "DQN trials (seeds seed0, seed0 + 1, ...)")
    seed0: int = option(PILOT_SEED0, f"first pilot seed (>= {PILOT_SEED0})")
    set: tuple[str, ...] = option(
        (),
        "AgentConfig fields changed from the reproduction's Taxi settings, "
        "FIELD=VALUE,FIELD=VALUE (a value may hold commas: "
        "assumed_delay_probs=0.3,0.6,0.1)",
    )
    out: str | None = option(None, "write the per-episode steps and the summary as JSON here")

    def __post_init__(self):
        if self.seed0 < PILOT_SEED0:
            raise ValueError(f"seed0 must be >= {PILOT_SEED0}: lower seeds may be the reproduction's")
        if self.set and "=" not in self.set[0]:
            raise ValueError(f"set expects FIELD=VALUE, got {self.set[0]!r}")
        try:
            specs(self.env, 1, 1, self.changes, self.seed0)
        except TypeError as exc:
            raise ValueError(str(exc)) from None

    @property
    def changes(self) -> dict:
        """FIELD=VALUE items; an item without "=" continues the previous value (the command line splits
        `assumed_delay_probs=0.3,0.6,0.1` at its commas)."""
        items: list[str] = []
        for part in self.set:
            if "=" in part or not items:
                items.append(part)
            else:
                items[-1] += "," + part
        return {k.replace("-", "_"): _value(v) for k, v in (s.split("=", 1) for s in items)}


def main(cfg: TaxiPilotConfig) -> int:
    changes = cfg.changes
    trial_specs = specs(cfg.env, cfg.episodes, cfg.trials, changes, cfg.seed0)
    from threadpoolctl import threadpool_limits

    from experiments.runner import run_trials

    t0, c0 = time.perf_counter(), time.process_time()
    seen: dict[int, list[int]] = {}

    def on_episode(i: int, rec: dict) -> None:  # progress on stderr: a long pilot can be read as it goes
        seen.setdefault(i, []).append(rec["steps"])
        if len(seen[i]) % 10 == 0:
            print(
                f"trial {i} episodes {len(seen[i])}: median steps of the last 10 {int(np.median(seen[i][-10:]))}, "
                f"{sum(seen[i])} steps, {time.process_time() - c0:.0f} CPU s",
                file=sys.stderr,
                flush=True,
            )

    with threadpool_limits(1, user_api="blas"):
        results = run_trials(trial_specs, on_episode=on_episode)
    steps = np.array([[e["steps"] for e in r.episodes] for r in results], np.float64)
    summary = {
        "env": cfg.env,
        "changes": changes,
        "seeds": [s.seed for s in trial_specs],
        "layouts": [s.layout for s in trial_specs],
        **convergence(steps),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "env_steps": int(steps.sum()),
    }
    print(json.dumps(summary))
    for k, row in enumerate(steps):
        med = [int(np.median(row[i : i + 10])) for i in range(0, len(row), 10)]
        print(f"trial {k} (seed {trial_specs[k].seed}): median steps per 10 episodes {med}", file=sys.stderr)
    if cfg.out:
        with open(cfg.out, "w") as fh:
            json.dump({**summary, "steps": steps.tolist()}, fh)
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(TaxiPilotConfig, argv, prog="python -m experiments pilot taxi"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments pilot taxi")
