"""Stable-Baselines3's DQN against this project's DQN on the paper's maze, in steps per CPU second, side by side.

    pip install --no-deps --target .cache/sb3 stable-baselines3==2.9.0
    python experiments/sb3_anchor.py --sb3-path .cache/sb3 [--against <other checkout>]

What a user would pick instead for the plain loop is Stable-Baselines3 (docs/results/REPORT.md cites it as the
anchor). Both sides learn the maze (layout `--layout`, `mdp` observations) with the paper's settings: one hidden
layer of 100 tanh units, RMSProp (lr 1e-3, alpha 0.99, eps 1e-8), Huber TD loss, gamma 0.9, one minibatch of 32 per
step from a 10,000-transition replay after 32 steps, the target network copied every 100 steps, epsilon 0.3 down
0.001 a step to 0.1. SB3 clips the gradient's norm at 10 by default; the project does not, so SB3 runs with
`max_grad_norm` 1e10 (it still computes the norm). Stable-Baselines3 is installed with `--no-deps` beside the
project (it would otherwise change the project's gymnasium) and is not a dependency.

Printed, in CPU seconds of each process (`time.process_time()`; torch and BLAS on one thread):
  sb3       one DQN learning for `--sb3-steps` environment steps;
  plain     one of this project's DQN trials alone (a batch of one), `--episodes` episodes;
  batched   `--trials` DQN trials in one lockstep batch, as `experiments reproduce` runs them;
and each project row's ratio to SB3. With `--against CHECKOUT` the project rows also run with that checkout's code
(same file, the other checkout first on the path), rounds alternating who goes first.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, replace

# Run as a file, this folder would come first on the path and shadow other modules: code comes from PYTHONPATH.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

from common.config import option  # noqa: E402  (after the path is set)

CONDITION = "maze-high-nodelay"  # DQN ignores feedback: any maze condition gives the same DQN trials


def sb3_rate(layout: int, steps: int, seed: int) -> dict:
    """Steps per CPU second of Stable-Baselines3's DQN on the maze, the paper's settings (module docstring)."""
    import torch
    from stable_baselines3 import DQN

    from common.envs.maze import MazeEnv

    torch.set_num_threads(1)
    start, floor, per_step = 0.3, 0.1, 0.001
    model = DQN(
        "MlpPolicy",
        MazeEnv(layout, "mdp"),
        learning_rate=1e-3,
        buffer_size=10_000,
        learning_starts=32,
        batch_size=32,
        tau=1.0,
        gamma=0.9,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=100,
        exploration_initial_eps=start,
        exploration_final_eps=floor,
        exploration_fraction=(start - floor) / per_step / steps,
        max_grad_norm=1e10,
        policy_kwargs={
            "net_arch": [100],
            "activation_fn": torch.nn.Tanh,
            "optimizer_class": torch.optim.RMSprop,
            "optimizer_kwargs": {"alpha": 0.99, "eps": 1e-8},
        },
        seed=seed,
        device="cpu",
    )
    c0 = time.process_time()
    model.learn(total_timesteps=steps)
    cpu = time.process_time() - c0
    return {"who": "sb3", "steps": steps, "cpu_s": round(cpu, 3), "steps_per_cpu_s": round(steps / cpu, 1)}


def project_rate(trials: int, episodes: int, layout: int) -> dict:
    """Steps per CPU second of `trials` of this checkout's DQN trials in one batch (1: a trial alone)."""
    from experiments import runner
    from experiments.conditions import BY_NAME, Scale, trial_spec

    runner.threadpool_limits(1, user_api="blas")
    scale = Scale(layouts=max(trials, 2), first_layout=layout, seed_block=4)
    specs = [replace(trial_spec(BY_NAME[CONDITION], "dqn", k, scale), episodes=episodes) for k in range(trials)]
    c0 = time.process_time()
    results = runner.run_trials(specs)
    cpu = time.process_time() - c0
    steps = sum(r.total_steps for r in results)
    who = "plain" if trials == 1 else "batched"
    return {"who": who, "steps": steps, "cpu_s": round(cpu, 3), "steps_per_cpu_s": round(steps / cpu, 1)}


def in_fresh_process(checkout: str, args: list[str], extra_path: str = "") -> dict:
    path = os.pathsep.join(p for p in (checkout, extra_path) if p)
    done = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--here", *args],
        cwd=checkout,
        env={**os.environ, "PYTHONPATH": path, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"{checkout}: {done.stderr[-800:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


@dataclass(frozen=True)
class AnchorConfig:
    """Stable-Baselines3's DQN against this project's DQN on the maze, steps per CPU second, side by side."""

    sb3_path: str = option("", "a folder holding stable_baselines3 (pip install --no-deps --target FOLDER ...)")
    against: str = option("", "another checkout of this project, whose DQN rows are run too")
    layout: int = option(120, "maze layout (both sides)")
    sb3_steps: int = option(20_000, "environment steps Stable-Baselines3's DQN learns for")
    episodes: int = option(100, "episodes of each project trial")
    trials: int = option(32, "trials of the batched row")
    rounds: int = option(2, "rounds, alternating which checkout goes first")
    here: str = option("", "run one row in this process: sb3, plain or batched (used by the command itself)")


def row(args: AnchorConfig, what: str, checkout: str) -> dict:
    if what == "sb3":
        flags = ["sb3", "--layout", str(args.layout), "--sb3-steps", str(args.sb3_steps)]
        return in_fresh_process(checkout, flags, os.path.abspath(args.sb3_path) if args.sb3_path else "")
    flags = [what, "--layout", str(args.layout), "--episodes", str(args.episodes), "--trials", str(args.trials)]
    return in_fresh_process(checkout, flags)


def compare(args: AnchorConfig) -> list[dict]:
    this = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sides = [("this", this)] + ([("other", os.path.abspath(args.against))] if args.against else [])
    print(f"load average {os.getloadavg()[0]:.2f}; SB3 from {args.sb3_path or 'the environment'}", flush=True)
    print(f"{'round':<6}{'row':<9}{'checkout':<9}{'steps':>9}{'CPU s':>9}{'steps/CPU s':>13}{'/ sb3':>8}", flush=True)
    rows = []
    for r in range(args.rounds):
        sb3 = row(args, "sb3", this) | {"round": r + 1, "checkout": "-"}
        rows.append(sb3)
        print(f"{r + 1:<6}{'sb3':<9}{'-':<9}{sb3['steps']:>9}{sb3['cpu_s']:>9.2f}{sb3['steps_per_cpu_s']:>13.0f}")
        for what in ("plain", "batched"):
            for who, path in sides if r % 2 == 0 else sides[::-1]:
                g = row(args, what, path) | {"round": r + 1, "checkout": who}
                g["ratio_to_sb3"] = round(g["steps_per_cpu_s"] / sb3["steps_per_cpu_s"], 2)
                rows.append(g)
                print(
                    f"{r + 1:<6}{what:<9}{who:<9}{g['steps']:>9}{g['cpu_s']:>9.2f}{g['steps_per_cpu_s']:>13.0f}"
                    f"{g['ratio_to_sb3']:>8.2f}",
                    flush=True,
                )
    print(f"load average at end {os.getloadavg()[0]:.2f}")
    return rows


def main(argv: list[str] | None = None) -> None:
    from common.config import parse_config

    args = parse_config(AnchorConfig, argv, prog="experiments/sb3_anchor.py")
    if args.here == "sb3":
        print(json.dumps(sb3_rate(args.layout, args.sb3_steps, seed=4)))
    elif args.here in ("plain", "batched"):
        trials = 1 if args.here == "plain" else args.trials
        print(json.dumps(project_rate(trials, args.episodes, args.layout)))
    elif args.here:
        raise SystemExit(f"--here must be sb3, plain or batched, got {args.here!r}")
    else:
        compare(args)


if __name__ == "__main__":
    main()
