"""`python -m experiments minigrid`: DQN-TAMER against DQN on a MiniGrid task with image observations and
the default CNN, on the in-process runner: steps per episode, mean over seeds with a 95% interval, as a PNG
and a JSON (docs/minigrid.png). Feedback comes from the simulated observer with the grid-world progress
rule (common/envs/gym_tasks.py: fewer turns-and-moves to the goal = +1)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np

from common.config import option

from common.agents import agent_config
from common.core.observer import ObserverConfig
from experiments.plots import plot_curves
from experiments.runner import TrialSpec, run_trials

ALGOS = ("dqn-tamer", "dqn")


def compare(
    env: str, seeds: int, episodes: int, observer: ObserverConfig = ObserverConfig(), **agent_overrides
) -> dict:
    """Steps per episode [seeds, episodes] of each algorithm (trials of one algorithm run batched)."""
    out = {}
    for algo in ALGOS:
        specs = [TrialSpec(env, agent_config(algo, **agent_overrides), observer, s, 0, episodes) for s in range(seeds)]
        t0 = time.perf_counter()
        results = run_trials(specs)
        out[algo] = {
            "steps": [[e["steps"] for e in r.episodes] for r in results],
            "returns": [r.returns.tolist() for r in results],
            "wall_s": time.perf_counter() - t0,
        }
    return out


@dataclass(frozen=True)
class MinigridConfig:
    """DQN-TAMER against DQN on a MiniGrid task with image observations and a CNN: OUT.png and OUT.json."""

    env: str = option("minigrid-empty", "environment")
    seeds: int = option(8, "trials per algorithm")
    episodes: int = option(25, "episodes per trial")
    out: str = option("docs/minigrid", "writes OUT.png and OUT.json")


def main(args: MinigridConfig) -> int:
    data = compare(args.env, args.seeds, args.episodes)
    curves, bands = {}, {}
    for algo, d in data.items():
        steps = np.asarray(d["steps"], float)
        mean, half = steps.mean(0), 1.96 * steps.std(0, ddof=1) / np.sqrt(len(steps))
        label = f"{algo} ({'with' if algo == 'dqn-tamer' else 'without'} feedback)"
        curves[label], bands[label] = mean, (mean - half, mean + half)
        print(
            f"{label}: {steps.sum():.0f} steps in {d['wall_s']:.1f} s; mean steps per episode "
            f"{steps.mean():.1f}, last 5 episodes {steps[:, -5:].mean():.1f}"
        )
    plot_curves(
        curves,
        f"{args.out}.png",
        f"{args.env}, CNN on the 7x7x3 view, {args.seeds} seeds (95% interval)",
        ylabel="steps per episode (fewer is better)",
        bands=bands,
    )
    with open(f"{args.out}.json", "w") as fh:
        json.dump({"env": args.env, "seeds": args.seeds, "episodes": args.episodes, **data}, fh)
    print(f"wrote {args.out}.png, {args.out}.json")
    return 0


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments minigrid")
