"""The configs and bodies of `python -m experiments reproduce`, `report` and `bench` (the table of commands is
experiments/__main__.py)."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, replace

from common.config import option
from experiments.conditions import BY_NAME
from experiments.declarations import DECLARATIONS, NEWEST


@dataclass(frozen=True)
class ReproduceConfig:
    """Every condition of the paper with all four agents: figures, claims with computed verdicts, timing (cached:
    re-running only re-plots)."""

    quick: bool = option(
        False,
        "the small form: 8 layouts, 40 maze episodes, no Taxi (--quick --only taxi-stop runs "
        "4 Taxi trials x 40 episodes), about 2 minutes on 2 free cores, written to "
        "runs/reproduce-quick unless --out is given",
    )
    declaration: str = option(
        NEWEST,
        "the declaration whose arms are run and whose claims decide (experiments/declarations.py)",
        choices=tuple(DECLARATIONS),
        metavar="ID",
    )
    replicate: int | None = option(
        None,
        "which of the declaration's runs (default 1; 2026-11-28 declares two, on fresh layouts and seeds each), "
        "written to its directory (docs/results/confirm/run-N; 2026-11-25: docs/results) unless --out is given",
        metavar="N",
    )
    against: str | None = option(
        None,
        "the other run's claims.json, for REPORT.md's settlement table (default: the other declared run's, "
        "where it exists)",
        metavar="CLAIMS_JSON",
    )
    layouts: int | None = option(None, "maze layouts (default: the declared run's; half honest, half misleading)")
    reps: int | None = option(None, "seeds per layout (default: the declared run's)")
    maze_episodes: int | None = option(None, "episodes per maze trial")
    taxi_episodes: int | None = option(None, "episodes per Taxi trial (both Taxi variants)")
    taxi_random_episodes: int | None = option(
        None, "episodes per trial of Gymnasium's Taxi (random passenger and destination) only"
    )
    taxi_trials: int | None = option(None, "trials per arm of Gymnasium's Taxi (default 4)")
    taxi_fixed_trials: int | None = option(None, "trials per arm of the fixed-task Taxi (default 4)")
    only: tuple[str, ...] = option(
        (), f"run only these conditions ({', '.join(BY_NAME)})", nargs="+", choices=tuple(BY_NAME), metavar="NAME"
    )
    out: str | None = option(None, "output directory (default: docs/results, or runs/reproduce-quick with --quick)")
    workers: int = option(2, "worker processes (1 = in this process)")
    ray: str | None = option(
        None,
        "run the trials as Ray tasks on that cluster, as `sweep --ray` does (docs/sweeps.md)",
        metavar="auto|local|ADDRESS",
    )
    no_progress: bool = option(False, "no progress bar")

    def __post_init__(self):
        if self.layouts is not None and self.layouts < 4:
            raise ValueError("--layouts must be at least 4 (intervals resample layouts)")
        runs = len(DECLARATIONS[self.declaration].runs)
        if self.replicate is not None and not 1 <= self.replicate <= runs:
            raise ValueError(f"--replicate: the declaration {self.declaration} declares runs 1-{runs}")
        if self.quick and self.replicate is not None:
            raise ValueError(
                "--quick runs the old trials (layouts 0-7, seed block 1), not a declared run: no --replicate"
            )


def reproduce_main(args: ReproduceConfig, argv: list[str]) -> int:
    from experiments.conditions import QUICK, select
    from experiments.declarations import get, missing_layouts
    from experiments.reproduce import reproduce

    conds = select(list(args.only))
    if args.quick and not args.only:  # Taxi's 1000-step episodes alone cost more than the quick form's minutes
        conds = [c for c in conds if not c.is_taxi]
    decl, replicate = get(args.declaration), (None if args.quick else args.replicate or 1)
    scale = QUICK if replicate is None else decl.scale(replicate)
    changes = {
        k: v
        for k, v in (
            ("layouts", args.layouts),
            ("reps", args.reps),
            ("maze_episodes", args.maze_episodes),
            ("taxi_episodes", args.taxi_episodes),
            ("taxi_random_episodes", args.taxi_random_episodes or args.taxi_episodes),
            ("taxi_trials", args.taxi_trials),
            ("taxi_fixed_trials", args.taxi_fixed_trials),
        )
        if v is not None
    }
    scale = replace(scale, **changes)
    if not all(c.is_taxi for c in conds) and (why := missing_layouts(scale)):
        print(f"error: {why}", file=sys.stderr)
        return 1
    out = args.out or ("runs/reproduce-quick" if replicate is None else decl.outs[replicate - 1])
    against = args.against or _other_run(decl, replicate, args.out)
    try:
        stats = reproduce(
            conds,
            scale,
            out,
            workers=args.workers,
            progress=not args.no_progress,
            argv=argv,
            ray=args.ray,
            declaration=decl.id,
            replicate=replicate,
            against=against,
        )
    except RuntimeError as exc:  # a worker or Ray failed: finished trials are cached, re-run resumes
        print(f"error: {exc}", file=sys.stderr)
        return 1
    with open(os.path.join(out, "claims.json")) as fh:
        verdicts = {k: v["verdict"] for k, v in json.load(fh)["claims"].items()}
    print(
        f"{stats.trials} trials ({stats.trials_run} run, {stats.trials_cached} cached, {stats.trials_shared} "
        f"shared) in {stats.total_s:.1f} s; wrote {out}/REPORT.md, claims.json, timing.json, *.png"
    )
    for claim, verdict in verdicts.items():
        print(f"  {claim}: {verdict}")
    return 0


def _other_run(decl, replicate: int | None, out: str | None) -> str | None:
    """The claims.json of the declaration's other run in its default directory, where this run is a declared one
    written to its own default directory and the other exists."""
    if replicate is None or out is not None or len(decl.runs) != 2:
        return None
    path = os.path.join(decl.outs[2 - replicate], "claims.json")
    return path if os.path.exists(path) else None


@dataclass(frozen=True)
class ReportConfig:
    """Every verdict, interval and figure recomputed from a per-trial table (docs/results/trials.csv.xz) without
    running a trial."""

    source: str = option(
        "",
        "the table (its directory's timing.json and claims.json give the run's scale and the previous verdicts)",
        flag="from",
        metavar="TABLE",
    )
    out: str = option("", "directory for claims.json, REPORT.md and the figures")
    n_boot: int | None = option(None, "bootstrap resamples (default: the declared number, as the reproduction)")
    against: str | None = option(
        None, "the other run's claims.json, for REPORT.md's settlement table", metavar="CLAIMS_JSON"
    )

    def __post_init__(self):
        if not self.source or not self.out:
            raise ValueError("--from TABLE and --out DIR are required")


def report_main(args: ReportConfig, argv: list[str]) -> int:
    """Recompute claims.json, REPORT.md and the figures from a per-trial table alone."""
    from experiments.evaluate import N_BOOT
    from experiments.reproduce import report_from_table
    from experiments.trialcache import read_json_or_none

    src = os.path.dirname(os.path.abspath(args.source))
    timing = read_json_or_none(os.path.join(src, "timing.json")) or {}
    if "scale" not in timing:
        print(
            f"error: {src}/timing.json (the run's scale and cost, beside the table) is missing or unreadable",
            file=sys.stderr,
        )
        return 1
    previous = (read_json_or_none(os.path.join(src, "claims.json")) or {}).get("previous", {})
    try:
        n_boot = N_BOOT if args.n_boot is None else args.n_boot
        result = report_from_table(args.source, args.out, timing, argv, n_boot, previous, args.against)
    except (OSError, ValueError, EOFError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}/claims.json, REPORT.md and the figures from {args.source} (no trial run)")
    for claim, c in result["claims"].items():
        print(f"  {claim}: {c['verdict']}")
    return 0


@dataclass(frozen=True)
class BenchConfig:
    """Speed-up of batched, parallel trials over the plain per-trial loop, measured side by side on the same trials;
    then the paper's MLP on the numpy path and on the torch path."""

    conditions: tuple[str, ...] = option(
        tuple(BY_NAME), "conditions to draw trials from", nargs="+", choices=tuple(BY_NAME), metavar="NAME"
    )
    trials: int = option(2, "trials per agent and condition")
    episodes: int = option(30, "episodes per trial")
    workers: int = option(2, "processes for the parallel mode")
    out: str | None = option(None, "also write the numbers to this JSON file")
    paths_only: bool = option(False, "only the network paths (numpy MLP vs torch MLP, on the first condition's trials)")

    def __post_init__(self):
        if self.trials < 1 or self.episodes < 1:
            raise ValueError("--trials and --episodes must be positive")


def bench_main(args: BenchConfig) -> int:
    from experiments.bench import bench, format_report
    from experiments.bench_paths import bench_paths, format_paths
    from experiments.conditions import ALGOS, QUICK, select, trial_spec

    if not args.paths_only:
        report = bench(list(args.conditions), args.trials, args.episodes, workers=args.workers, out=args.out)
        print(format_report(report))
    first = select(list(args.conditions))[:1]  # the torch path is slower: one condition's trials
    scale = replace(QUICK, maze_episodes=args.episodes, taxi_episodes=args.episodes, taxi_random_episodes=args.episodes)
    specs = [
        trial_spec(c, algo, k, scale) for c in first for algo in ALGOS if algo in c.arms for k in range(args.trials)
    ]
    print(format_paths(bench_paths(specs)))
    return 0
