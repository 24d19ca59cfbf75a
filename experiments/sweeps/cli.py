"""`python -m experiments sweep`: the command line of a sweep (grid, YAML file, contrasts, Ray)."""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass

from common.config import fail, option
from experiments.conditions import FULL
from experiments.evaluate import N_BOOT
from experiments.sweeps.grid import Sweep, coerce, from_mapping, load_yaml, parse_assignment, parse_values, split_top


@dataclass(frozen=True)
class SweepConfig:
    """A grid of config fields, trials per cell: one tidy table (CSV, Parquet), a summary per cell, a figure per
    group of cells, named contrasts with verdicts (cached: re-running only re-plots)."""

    file: str | None = option(
        None,
        "sweep file (keys: name, trials, layouts, set, grid, contrasts, legend); the options below override it",
        positional=True,
        nargs="?",
        metavar="SWEEP.yaml",
    )
    grid: tuple[str, ...] = option(
        (),
        "swept fields, e.g. observer.p_feedback=0.1,0.5 agent.algo=dqn,dqn-tamer "
        "(tuples in brackets: observer.delay_probs=[1,0,0],[0.3,0.6,0.1])",
        nargs="+",
        metavar="FIELD=V1,V2",
    )
    set: tuple[str, ...] = option(
        (), "fixed settings for every cell, e.g. env=maze-pomdp agent.lr=0.003", nargs="+", metavar="FIELD=V"
    )
    trials: int | None = option(None, "trials per cell (default: 10, or the file's)")
    layouts: str | None = option(
        None, f"maze layouts the trials cycle over (default: all {FULL.layouts})", metavar="L1,L2"
    )
    contrast: tuple[str, ...] = option(
        (),
        "a named contrast, e.g. 'agent.algo=dqn-tamer - agent.algo=dqn' on mean "
        "ln steps (prefix 'return:', 'success:' or 'ln_steps_last10:' for another "
        "metric); repeatable",
        nargs="+",
        metavar="'F=A - F=B'",
    )
    legend: str | None = option(
        None,
        "swept field drawn as lines in each figure (default: agent.algo if swept, "
        "else the last swept field); the other fields make the groups",
        metavar="FIELD",
    )
    name: str | None = option(None, "sweep name, used in titles (default: the file's or 'sweep')")
    out: str = option("runs/sweep", "output directory")
    cache: str | None = option(None, "trial cache shared between sweeps (default: OUT/cache)", metavar="DIR")
    workers: int = option(2, "local worker processes (1 = in this process)")
    ray: str | None = option(
        None,
        "run the trials as Ray tasks: 'auto' (the running cluster), an address "
        "(HOST:PORT) or 'local' (a private instance); needs pip install '.[ray]'",
        metavar="auto|local|ADDRESS",
    )
    boot: int = option(N_BOOT, "bootstrap resamples")
    no_progress: bool = option(False, "no progress bar")

    def __post_init__(self):
        if self.workers < 1 or self.boot < 10:
            raise ValueError("--workers must be >= 1 and --boot >= 10")


def build_sweep(args) -> Sweep:
    """The sweep from the file (if any) and the options; ValueError with a one-line reason."""
    kw = load_yaml(args.file) if args.file else from_mapping({})
    for item in args.grid:
        path, rhs = parse_assignment(item)
        kw["grid"][path] = parse_values(path, rhs)
    for item in args.set:
        path, rhs = parse_assignment(item)
        values = parse_values(path, rhs)
        if len(values) != 1:
            raise ValueError(f"--set {item!r}: one value per field (use --grid to sweep)")
        kw["fixed"][path] = values[0]
        kw["grid"].pop(path, None)  # a fixed setting overrides the file's sweep of that field
    if args.trials is not None:
        kw["trials"] = args.trials
    if args.layouts is not None:
        kw["layouts"] = tuple(coerce("layout", x.strip()) for x in split_top(args.layouts))
    kw["contrasts"] = list(kw.get("contrasts", [])) + list(args.contrast)
    for key in ("legend", "name"):
        if getattr(args, key) is not None:
            kw[key] = getattr(args, key)
    return Sweep(**kw)


def main(args: SweepConfig, argv: list[str]) -> int:
    from experiments.sweeps.report import print_outcome, run_sweep

    try:
        sweep = build_sweep(args)
        from experiments.sweeps.analysis import parse_contrast

        for c in sweep.contrasts:
            parse_contrast(c, sweep)
    except ValueError as exc:
        fail(str(exc))
    try:
        result = run_sweep(
            sweep,
            args.out,
            workers=args.workers,
            ray=args.ray,
            progress=not args.no_progress,
            cache_dir=args.cache,
            n_boot=args.boot,
            command="python -m experiments " + shlex.join(argv),
        )
    except RuntimeError as exc:  # a worker or Ray failed: finished trials are cached, re-run resumes
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"interrupted: finished trials are cached in {args.cache or args.out + '/cache'}; the same command resumes",
            file=sys.stderr,
        )
        return 130
    print_outcome(result, args.out)
    return 0
