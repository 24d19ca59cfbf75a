"""`python -m experiments bench`: speed of the reproduction machinery against the plain loop, side by side.

The same subset of trials is run three ways in one invocation:
  plain    each trial alone (a batch of one), one after another, in this process: what running the
           trials with a per-trial loop costs with this core;
  batched  all trials in lockstep batches (one per environment kind), in this process;
  parallel the batches split over `workers` processes, as `reproduce` runs them.
Every way must give the same returns for every trial (checked; the run fails otherwise), so the ratios
are pure speed.
"""

from __future__ import annotations

import json
import time

import numpy as np

from dataclasses import replace

from experiments.conditions import ALGOS, QUICK, select, trial_spec
from experiments.runner import run_trials
from experiments.sweeps.execute import run_local
from experiments.trialcache import Task, make_jobs, trial_key


def bench(conditions: list[str], trials: int, episodes: int, workers: int = 2, out: str | None = None) -> dict:
    conds = select(conditions)
    scale = replace(QUICK, maze_episodes=episodes, taxi_episodes=episodes, taxi_random_episodes=episodes)
    specs = [trial_spec(c, algo, k, scale) for c in conds for algo in ALGOS if algo in c.arms for k in range(trials)]

    t0 = time.perf_counter()
    plain = [run_trials([s])[0] for s in specs]
    t_plain = time.perf_counter() - t0

    t0 = time.perf_counter()
    batched = {}
    for env in dict.fromkeys(s.env for s in specs):
        group = [s for s in specs if s.env == env]
        for s, r in zip(group, run_trials(group)):
            batched[id(s)] = r
    t_batched = time.perf_counter() - t0

    # Parallel: the reproduce path (jobs of one environment kind split over workers). Every trial runs,
    # even where reproduce would share identical trials between conditions, so all three do the same work.
    # The same process pool as sweeps and the reproduction (`experiments.sweeps.execute.run_local`).
    jobs = [[(t.key, t.spec, 1) for t in job] for job in make_jobs([Task(trial_key(s), s) for s in specs], workers)]
    steps_par = {}

    def on_message(msg: tuple) -> None:
        if msg[0] == "trial":  # ("trial", key, record, progress already reported)
            steps_par[msg[1]] = msg[2]["total_steps"]

    t0 = time.perf_counter()
    run_local(jobs, workers, on_message)
    t_parallel = time.perf_counter() - t0

    mismatches = [
        i
        for i, s in enumerate(specs)
        if not np.array_equal(plain[i].returns, batched[id(s)].returns)
        or plain[i].total_steps != steps_par[trial_key(s)]
    ]
    if mismatches:
        raise RuntimeError(f"{len(mismatches)} trials differ between the plain loop and the batched runs")
    total_steps = int(sum(r.total_steps for r in plain))
    report = {
        "conditions": [c.name for c in conds],
        "trials_per_agent": trials,
        "episodes": episodes,
        "trials": len(specs),
        "env_steps": total_steps,
        "workers": workers,
        "plain_s": t_plain,
        "batched_s": t_batched,
        "parallel_s": t_parallel,
        "speedup_batched": t_plain / t_batched,
        "speedup_parallel": t_plain / t_parallel,
        "plain_steps_per_s": total_steps / t_plain,
        "parallel_steps_per_s": total_steps / t_parallel,
    }
    if out:
        with open(out, "w") as fh:
            json.dump(report, fh, indent=1)
    return report


def format_report(r: dict) -> str:
    return "\n".join(
        [
            f"bench: {r['trials']} trials ({', '.join(r['conditions'])}; {r['trials_per_agent']} per agent, "
            f"{r['episodes']} episodes), {r['env_steps']} environment steps; identical returns in every mode",
            f"  plain loop (each trial alone, one after another): {r['plain_s']:8.1f} s  "
            f"({r['plain_steps_per_s']:.0f} steps/s)",
            f"  batched, 1 process:                               {r['batched_s']:8.1f} s  "
            f"speed-up x{r['speedup_batched']:.1f}",
            f"  batched, {r['workers']} processes:                       {r['parallel_s']:8.1f} s  "
            f"speed-up x{r['speedup_parallel']:.1f}",
        ]
    )
