"""python -m experiments COMMAND: experiments on the in-process runner (virtual clock), and their tools.

Every command has --help; every setting is a field of the command's documented config (common/config.py)."""

from __future__ import annotations

import csv
import json
import os
import sys
import time

from common.agents import AgentConfig
from common.config import Command, config_record, fail, run_commands
from experiments.run_config import RunConfig


def agent_of(config: RunConfig) -> AgentConfig:
    """The run's agent settings (RunConfig fills them from the algo's preset when none are given)."""
    if config.agent is None:
        raise ValueError(f"no agent settings for {config.algo}")
    return config.agent


def check_run(config: RunConfig) -> None:
    """The env and the agent's networks can be built (else a one-line ValueError naming what is wrong)."""
    from common.agents.torch_agent import check_agent
    from common.envs import make_env

    env, _ = make_env(config.task.env, config.task.layout, config.task.teacher_rule)
    check_agent(agent_of(config), env)


def cmd_run(config: RunConfig) -> int:
    from tqdm import tqdm

    from experiments.plots import plot_curves
    from experiments.runner import TrialSpec, run_trials
    from experiments.trial_types import EPISODE_FIELDS

    os.makedirs(config.out, exist_ok=True)
    task = config.task
    spec = TrialSpec(
        task.env,
        agent_of(config),
        config.observer,
        task.seed,
        task.layout,
        config.episodes,
        task.teacher_rule,
        config.step_seconds,
    )
    with open(os.path.join(config.out, "config.json"), "w") as fh:
        json.dump(config_record(config), fh, indent=2)  # the whole tree: task, agent, observer
    bar = tqdm(total=config.episodes, desc=f"{config.algo} on {task.env}", unit="ep", file=sys.stderr)

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
    plot_curves(
        {config.algo: result.returns},
        os.path.join(config.out, "curve.png"),
        f"{config.algo} on {task.env} layout {task.layout}, seed {task.seed}",
        stop_episode=config.observer.stop_episode,
    )
    summary = {
        "episodes": len(result.episodes),
        "steps": result.total_steps,
        "wall_s": round(wall, 3),
        "returns": result.returns.tolist(),
        "delay": {"observer": result.delay},
    }
    with open(os.path.join(config.out, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    print(
        f"{config.episodes} episodes, {result.total_steps} steps in {wall:.1f} s "
        f"({result.total_steps / max(wall, 1e-9):.0f} steps/s); wrote {config.out}/episodes.csv, summary.json, "
        f"curve.png"
    )
    return 0


def run_main(config: RunConfig) -> int:
    try:
        check_run(config)
    except (ValueError, OSError) as exc:
        fail(str(exc))
    return cmd_run(config)


def commands() -> dict:
    from experiments.bench_compare import BenchCompareConfig, main as bench_compare
    from experiments.alpha_pilot import AlphaPilotConfig, main as alpha_pilot
    from experiments.commands import BenchConfig, ReportConfig, ReproduceConfig, bench_main, report_main
    from experiments.commands import reproduce_main
    from experiments.console_pilot import ConsolePilotConfig, main as console_pilot
    from experiments.delay_check import DelayCheckConfig, main as delay_check
    from experiments.machines import MachinesConfig, main as machines
    from experiments.maze_pilot import MazePilotConfig, main as maze_pilot
    from experiments.minigrid import MinigridConfig, main as minigrid
    from experiments.power import PowerConfig, main as power
    from experiments.report_runs import SettleConfig, settle_main
    from experiments.sweeps.bench import SweepBenchConfig, main as sweep_bench
    from experiments.sweeps.cli import SweepConfig, main as sweep
    from experiments.taxi_pilot import TaxiPilotConfig, main as taxi_pilot

    return {
        "run": Command(RunConfig, run_main),
        "sweep": Command(SweepConfig, sweep, argv=True),
        "reproduce": Command(ReproduceConfig, reproduce_main, argv=True),
        "report": Command(ReportConfig, report_main, argv=True),
        "settle": Command(SettleConfig, settle_main),
        "pilot": {
            "": "how a setting was chosen on pilot seeds, never the trials that use it",
            "maze": Command(MazePilotConfig, maze_pilot),
            "taxi": Command(TaxiPilotConfig, taxi_pilot),
            "console": Command(ConsolePilotConfig, console_pilot),
            "alpha": Command(AlphaPilotConfig, alpha_pilot),
        },
        "minigrid": Command(MinigridConfig, minigrid),
        "machines": Command(MachinesConfig, machines),
        "bench": Command(BenchConfig, bench_main),
        "sweep-bench": Command(SweepBenchConfig, sweep_bench),
        "bench-compare": Command(BenchCompareConfig, bench_compare),
        "delay-check": Command(DelayCheckConfig, delay_check),
        "power": Command(PowerConfig, power),
    }


def main(argv: list[str] | None = None) -> int:
    return run_commands("python -m experiments", __doc__, commands(), argv)


if __name__ == "__main__":
    sys.exit(main())
