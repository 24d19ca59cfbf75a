"""python -m experiments {run, sweep, reproduce, report, bench, bench-compare}: experiments on the in-process
runner (virtual clock)."""
from __future__ import annotations

import csv
import json
import os
import sys
import time

from common.config import ConfigParser, add_config_arguments, config_from_namespace, config_record
from experiments.run_config import RunConfig


def check_run(config: RunConfig) -> None:
    """The env and the agent's networks can be built (else a one-line ValueError naming what is wrong)."""
    from common.agents.torch_agent import check_agent
    from common.envs import make_env

    env, _ = make_env(config.task.env, config.task.layout, config.task.teacher_rule)
    check_agent(config.agent, env)


def cmd_run(config: RunConfig) -> int:
    from tqdm import tqdm

    from experiments.plots import plot_curves
    from experiments.runner import EPISODE_FIELDS, TrialSpec, run_trials

    os.makedirs(config.out, exist_ok=True)
    task = config.task
    spec = TrialSpec(task.env, config.agent, config.observer, task.seed, task.layout, config.episodes,
                     task.teacher_rule, config.step_seconds)
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
    plot_curves({config.algo: result.returns}, os.path.join(config.out, "curve.png"),
                f"{config.algo} on {task.env} layout {task.layout}, seed {task.seed}",
                stop_episode=config.observer.stop_episode)
    summary = {"episodes": len(result.episodes), "steps": result.total_steps, "wall_s": round(wall, 3),
               "returns": result.returns.tolist(), "delay": {"observer": result.delay}}
    with open(os.path.join(config.out, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    print(f"{config.episodes} episodes, {result.total_steps} steps in {wall:.1f} s "
          f"({result.total_steps / max(wall, 1e-9):.0f} steps/s); wrote {config.out}/episodes.csv, summary.json, "
          f"curve.png")
    return 0


def cmd_reproduce(args, argv: list[str]) -> int:
    from dataclasses import replace

    from experiments.conditions import FULL, QUICK, select
    from experiments.reproduce import reproduce

    conds = select(args.only)
    if args.quick and not args.only:  # Taxi's 1000-step episodes alone cost more than the quick form's minutes
        conds = [c for c in conds if not c.is_taxi]
    scale = QUICK if args.quick else FULL
    changes = {k: v for k, v in (("layouts", args.layouts), ("reps", args.reps),
                                 ("maze_episodes", args.maze_episodes), ("taxi_episodes", args.taxi_episodes),
                                 ("taxi_random_episodes", args.taxi_random_episodes or args.taxi_episodes),
                                 ("taxi_trials", args.taxi_trials), ("taxi_fixed_trials", args.taxi_fixed_trials))
               if v is not None}
    scale = replace(scale, **changes)
    out = args.out or ("runs/reproduce-quick" if args.quick else "docs/results")
    args.out = out
    try:
        stats = reproduce(conds, scale, out, workers=args.workers, progress=not args.no_progress, argv=argv,
                          ray=args.ray)
    except RuntimeError as exc:  # a worker or Ray failed: finished trials are cached, re-run resumes
        print(f"error: {exc}", file=sys.stderr)
        return 1
    with open(os.path.join(args.out, "claims.json")) as fh:
        verdicts = {k: v["verdict"] for k, v in json.load(fh)["claims"].items()}
    print(f"{stats.trials} trials ({stats.trials_run} run, {stats.trials_cached} cached, {stats.trials_shared} "
          f"shared) in {stats.total_s:.1f} s; wrote {args.out}/REPORT.md, claims.json, timing.json, *.png")
    for claim, verdict in verdicts.items():
        print(f"  {claim}: {verdict}")
    return 0


def cmd_report(args, argv: list[str]) -> int:
    """Recompute claims.json, REPORT.md and the figures from a per-trial table alone."""
    from experiments.reproduce import report_from_table
    from experiments.trialcache import read_json_or_none

    src = os.path.dirname(os.path.abspath(args.source))
    timing = read_json_or_none(os.path.join(src, "timing.json")) or {}
    if "scale" not in timing:
        print(f"error: {src}/timing.json (the run's scale and cost, beside the table) is missing or unreadable",
              file=sys.stderr)
        return 1
    previous = (read_json_or_none(os.path.join(src, "claims.json")) or {}).get("previous", {})
    try:
        result = report_from_table(args.source, args.out, timing, argv, args.n_boot, previous)
    except (OSError, ValueError, EOFError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}/claims.json, REPORT.md and the figures from {args.source} (no trial run)")
    for claim, c in result["claims"].items():
        print(f"  {claim}: {c['verdict']}")
    return 0


def cmd_bench(args) -> int:
    from experiments.bench import bench, format_report
    from experiments.bench_paths import bench_paths, format_paths
    from dataclasses import replace

    from experiments.conditions import ALGOS, QUICK, select, trial_spec

    if not args.paths_only:
        report = bench(args.conditions, args.trials, args.episodes, workers=args.workers, out=args.out)
        print(format_report(report))
    first = select(args.conditions)[:1]  # the torch path is slower: one condition's trials
    scale = replace(QUICK, maze_episodes=args.episodes, taxi_episodes=args.episodes, taxi_random_episodes=args.episodes)
    specs = [trial_spec(c, algo, k, scale) for c in first for algo in ALGOS if algo in c.arms
             for k in range(args.trials)]
    print(format_paths(bench_paths(specs)))
    return 0


def cmd_bench_compare(args, parser) -> int:
    from experiments.bench_compare import bench_compare

    if args.rounds < 1 or args.trials < 1 or args.episodes < 1:
        parser.error("--rounds, --trials and --episodes must be positive")
    try:
        result = bench_compare(args.against, args.rounds, args.envs, args.trials, args.episodes)
    except (ValueError, RuntimeError) as exc:
        parser.error(str(exc))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


def add_bench_parser(sub, by_name):
    p_bench = sub.add_parser("bench", help="speed-up of batched, parallel trials over the plain per-trial "
                             "loop, measured side by side on the same trials")
    p_bench.add_argument("--conditions", nargs="+", default=list(by_name), choices=list(by_name),
                         help="conditions to draw trials from (default: all)")
    p_bench.add_argument("--trials", type=int, default=2, help="trials per agent and condition (default: 2)")
    p_bench.add_argument("--episodes", type=int, default=30, help="episodes per trial (default: 30)")
    p_bench.add_argument("--workers", type=int, default=2, help="processes for the parallel mode (default: 2)")
    p_bench.add_argument("--out", default=None, help="also write the numbers to this JSON file")
    p_bench.add_argument("--paths-only", action="store_true", help="only the network paths (numpy MLP vs "
                         "torch MLP, on the first condition's trials)")
    return p_bench


def add_report_parser(sub) -> None:
    p_report = sub.add_parser("report", help="every verdict, interval and figure recomputed from a per-trial "
                              "table (docs/results/trials.csv.gz) without running a trial")
    p_report.add_argument("--from", dest="source", required=True, metavar="TABLE",
                          help="the table (its directory's timing.json and claims.json give the run's scale and "
                          "the previous verdicts)")
    p_report.add_argument("--out", required=True, help="directory for claims.json, REPORT.md and the figures")
    p_report.add_argument("--n-boot", type=int, default=None, help="bootstrap resamples (default: the declared "
                          "number, as the reproduction)")


def add_delay_check(sub):
    from experiments.delay_check import DelayCheckConfig

    p_delay = sub.add_parser("delay-check", help=DelayCheckConfig.__doc__, description=DelayCheckConfig.__doc__)
    add_config_arguments(p_delay, DelayCheckConfig)
    return p_delay


def cmd_delay_check(args, parser) -> int:
    from experiments.delay_check import DelayCheckConfig, main as delay_check_main

    try:
        check = config_from_namespace(DelayCheckConfig, args)
    except ValueError as exc:
        parser.error(str(exc))
    return delay_check_main(check)


def main(argv: list[str] | None = None) -> int:
    from experiments.conditions import BY_NAME

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = ConfigParser(prog="python -m experiments", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help=RunConfig.__doc__, description=RunConfig.__doc__)
    add_config_arguments(p_run, RunConfig)
    from experiments.sweeps import cli as sweep_cli
    p_sweep = sub.add_parser("sweep", help=sweep_cli.HELP, description=sweep_cli.HELP)
    sweep_cli.add_arguments(p_sweep)
    p_rep = sub.add_parser("reproduce", help="every condition of the paper with all four agents: figures, "
                           "claims with computed verdicts, timing (cached: re-running only re-plots)")
    p_rep.add_argument("--quick", action="store_true", help="the small form: 8 layouts, 40 maze episodes, no Taxi "
                       "(--quick --only taxi-stop runs 4 Taxi trials x 40 episodes), about 2 minutes on 2 free "
                       "cores, written to runs/reproduce-quick unless --out is given")
    p_rep.add_argument("--layouts", type=int, help="maze layouts (default 60: 30 honest, 30 misleading, all "
                       "generated)")
    p_rep.add_argument("--reps", type=int, help="seeds per layout (default 1)")
    p_rep.add_argument("--maze-episodes", type=int, help="episodes per maze trial")
    p_rep.add_argument("--taxi-episodes", type=int, help="episodes per Taxi trial (both Taxi variants)")
    p_rep.add_argument("--taxi-random-episodes", type=int,
                       help="episodes per trial of Gymnasium's Taxi (random passenger and destination) only")
    p_rep.add_argument("--taxi-trials", type=int, help="trials per arm of Gymnasium's Taxi (default 6)")
    p_rep.add_argument("--taxi-fixed-trials", type=int, help="trials per arm of the fixed-task Taxi (default 4)")
    p_rep.add_argument("--only", nargs="+", metavar="NAME", choices=list(BY_NAME),
                       help=f"run only these conditions ({', '.join(BY_NAME)})")
    p_rep.add_argument("--out", default=None, help="output directory (default: docs/results)")
    p_rep.add_argument("--workers", type=int, default=2, help="worker processes (default: 2; 1 = in this process)")
    p_rep.add_argument("--ray", default=None, metavar="auto|local|ADDRESS",
                       help="run the trials as Ray tasks on that cluster, as `sweep --ray` does (docs/sweeps.md)")
    p_rep.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_report_parser(sub)
    p_bench = add_bench_parser(sub, BY_NAME)
    p_cmp = sub.add_parser("bench-compare", help="the in-process runner of this checkout against another (a "
                           "worktree of an earlier commit), plain and batched, alternating, round after round: "
                           "steps/s ratios per round, the median ratio")
    p_cmp.add_argument("--against", required=True, help="the other checkout's directory")
    p_cmp.add_argument("--rounds", type=int, default=3, help="rounds; each runs both, alternating who goes first "
                       "(default: 3)")
    p_cmp.add_argument("--envs", nargs="+", default=["maze", "taxi"], help="environments (default: maze taxi)")
    p_cmp.add_argument("--trials", type=int, default=1, help="trials per agent and environment (default: 1)")
    p_cmp.add_argument("--episodes", type=int, default=10, help="episodes per trial (default: 10)")
    p_cmp.add_argument("--out", default=None, help="also write every run's figures and the ratios to this JSON file")
    p_delay = add_delay_check(sub)
    args = parser.parse_args(argv)
    if args.command == "delay-check":
        return cmd_delay_check(args, p_delay)
    if args.command == "bench-compare":
        return cmd_bench_compare(args, p_cmp)
    if args.command == "sweep":
        return sweep_cli.main(args, argv, p_sweep)
    if args.command == "reproduce":
        if args.layouts is not None and args.layouts < 4:
            p_rep.error("--layouts must be at least 4 (intervals resample layouts)")
        return cmd_reproduce(args, argv)
    if args.command == "report":
        if args.n_boot is None:
            from experiments.evaluate import N_BOOT
            args.n_boot = N_BOOT
        return cmd_report(args, argv)
    if args.command == "bench":
        if args.trials < 1 or args.episodes < 1:
            p_bench.error("--trials and --episodes must be positive")
        return cmd_bench(args)
    if args.command == "run":
        try:
            config = config_from_namespace(RunConfig, args)
            check_run(config)
        except (ValueError, OSError) as exc:
            p_run.error(str(exc))
        return cmd_run(config)
    return 2


if __name__ == "__main__":
    sys.exit(main())
