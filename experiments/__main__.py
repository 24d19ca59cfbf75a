"""python -m experiments {run, ...}: experiments on the in-process runner (virtual clock)."""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time

from common.config import add_config_arguments, config_from_namespace, config_record
from experiments.run_config import RunConfig


def cmd_run(config: RunConfig) -> int:
    from tqdm import tqdm

    from experiments.plots import plot_curves
    from experiments.runner import EPISODE_FIELDS, TrialSpec, run_trials

    os.makedirs(config.out, exist_ok=True)
    spec = TrialSpec(config.env, config.agent(), config.observer(), config.seed, config.layout, config.episodes)
    with open(os.path.join(config.out, "config.json"), "w") as fh:
        json.dump({"run": config_record(config), "agent": config_record(spec.agent),
                   "observer": config_record(spec.observer)}, fh, indent=2)
    bar = tqdm(total=config.episodes, desc=f"{config.algo} on {config.env}", unit="ep", file=sys.stderr)

    def on_episode(_trial: int, rec: dict) -> None:
        bar.update(1)
        bar.set_postfix(ret=f"{rec['return']:.2f}", steps=rec["steps"], fb=rec["feedback_credited"])

    t0 = time.perf_counter()
    result = run_trials([spec], on_episode=on_episode)[0]
    wall = time.perf_counter() - t0
    bar.close()
    with open(os.path.join(config.out, "episodes.csv"), "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=EPISODE_FIELDS)
        writer.writeheader()
        writer.writerows(result.episodes)
    plot_curves({config.algo: result.returns}, os.path.join(config.out, "curve.png"),
                f"{config.algo} on {config.env} layout {config.layout}, seed {config.seed}",
                stop_episode=config.stop_episode)
    print(f"{config.episodes} episodes, {result.total_steps} steps in {wall:.1f} s "
          f"({result.total_steps / max(wall, 1e-9):.0f} steps/s); wrote {config.out}/episodes.csv, curve.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help=RunConfig.__doc__, description=RunConfig.__doc__)
    add_config_arguments(p_run, RunConfig)
    args = parser.parse_args(argv)
    if args.command == "run":
        try:
            config = config_from_namespace(RunConfig, args)
        except (ValueError, OSError) as exc:
            p_run.error(str(exc))
        return cmd_run(config)
    return 2


if __name__ == "__main__":
    sys.exit(main())
