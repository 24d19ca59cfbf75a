"""`python -m experiments sweep`: the command line of a sweep (grid, YAML file, contrasts, Ray)."""
from __future__ import annotations

import argparse
import shlex

from experiments.evaluate import N_BOOT
from experiments.sweeps.grid import Sweep, coerce, from_mapping, load_yaml, parse_assignment, parse_values, split_top

HELP = ("a grid of config fields, trials per cell: one tidy table (CSV, Parquet), a summary per cell, a "
        "figure per group of cells, named contrasts with verdicts (cached: re-running only re-plots)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", nargs="?", default=None, metavar="SWEEP.yaml",
                   help="sweep file (keys: name, trials, layouts, set, grid, contrasts, legend); "
                        "the options below override it")
    p.add_argument("--grid", nargs="+", default=[], metavar="FIELD=V1,V2",
                   help="swept fields, e.g. observer.p_feedback=0.1,0.5 agent.algo=dqn,dqn-tamer "
                        "(tuples in brackets: observer.delay_probs=[1,0,0],[0.3,0.6,0.1])")
    p.add_argument("--set", nargs="+", default=[], metavar="FIELD=V",
                   help="fixed settings for every cell, e.g. env=maze-pomdp agent.lr=0.003")
    p.add_argument("--trials", type=int, default=None, help="trials per cell (default: 10, or the file's)")
    p.add_argument("--layouts", default=None, metavar="L1,L2",
                   help="maze layouts the trials cycle over (default: all 10)")
    p.add_argument("--contrast", action="append", default=[], metavar="'F=A - F=B'",
                   help="a named contrast, e.g. 'agent.algo=dqn-tamer - agent.algo=dqn' on mean ln steps (prefix "
                        "'return:', 'success:' or 'ln_steps_last10:' for another metric); repeatable")
    p.add_argument("--legend", default=None, metavar="FIELD",
                   help="swept field drawn as lines in each figure (default: agent.algo if swept, else the "
                        "last swept field); the other fields make the groups")
    p.add_argument("--name", default=None, help="sweep name, used in titles (default: the file's or 'sweep')")
    p.add_argument("--out", default="runs/sweep", help="output directory (default: runs/sweep)")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="trial cache shared between sweeps (default: OUT/cache)")
    p.add_argument("--workers", type=int, default=2, help="local worker processes (default: 2; 1 = in this process)")
    p.add_argument("--ray", default=None, metavar="auto|local|ADDRESS",
                   help="run the trials as Ray tasks: 'auto' (the running cluster), an address (HOST:PORT) "
                        "or 'local' (a private instance); needs pip install '.[ray]'")
    p.add_argument("--boot", type=int, default=N_BOOT, help=f"bootstrap resamples (default: {N_BOOT})")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


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


def main(args, argv: list[str], parser: argparse.ArgumentParser) -> int:
    from experiments.sweeps.report import print_outcome, run_sweep

    if args.workers < 1 or args.boot < 10:
        parser.error("--workers must be >= 1 and --boot >= 10")
    try:
        sweep = build_sweep(args)
        from experiments.sweeps.analysis import parse_contrast
        for c in sweep.contrasts:
            parse_contrast(c, sweep)
    except ValueError as exc:
        parser.error(str(exc))
    try:
        result = run_sweep(sweep, args.out, workers=args.workers, ray=args.ray, progress=not args.no_progress,
                           cache_dir=args.cache, n_boot=args.boot,
                           command="python -m experiments " + shlex.join(argv))
    except RuntimeError as exc:  # a worker or Ray failed: finished trials are cached, re-run resumes
        parser.exit(1, f"error: {exc}\n")
    except KeyboardInterrupt:
        parser.exit(130, f"interrupted: finished trials are cached in {args.cache or args.out + '/cache'}; "
                         "the same command resumes\n")
    print_outcome(result, args.out)
    return 0
