"""python -m services.replay LOG.mcap {summary, play, retrain}: a recorded session, offline.

  summary   counts, losses, what became of every feedback, per-episode returns, learning-curve plot
  play      re-publish the session over Zenoh at the recorded pace (or faster)
  retrain   feed a fresh learner the recorded inputs in the recorded order; says whether its final weights
            equal the live learner's bit for bit (exit 0 if they do, 1 if not, 2 if the log cannot tell);
            with --screen-delay / --screen-credit: how well each credit setting predicts the person's presses it
            was not fitted on (held-out log-likelihood, services/replay/heldout.py)
  size      bytes per 1,000 steps, and per topic

LOG may be a run directory (its session.mcap). A log cut short by a crash is read up to its last complete
chunk, a damaged chunk is skipped and the reading goes on, each with a warning saying what was lost.

Exit codes of `summary`: 0 every message of the log was read; 1 the log was read but data was lost (cut off
at the end, damaged chunks skipped, undecodable messages: each named on a `lost:` line); 2 there is no log to
read (no such file, an empty file, a directory without session.mcap, a file that is not MCAP), in one line,
or `--write` cannot finish the run now (its launcher or services still run).

`summary --write` on a run directory whose launcher was killed (summary.json still `{"outcome": "running"}`)
writes its summary.json and learning_curve.png from the log, outcome `interrupted`, as the launcher would have.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import threading
import time
import warnings
from pathlib import Path

from common.core.delay_model import REFERENCES


def _warn_to_stderr(message, category, filename, lineno, file=None, line=None):
    print(f"warning: {message}", file=sys.stderr)


def cmd_summary(args) -> int:
    from services.replay.curve import plot_summary
    from services.replay.summary import format_summary, summarize

    s = None
    if args.write:  # a run whose launcher was killed: its summary.json, from the log
        from services.launcher.rundir import RunDirError
        from services.launcher.unfinished import finish_from_log

        log = Path(args.log)
        try:
            s, line = finish_from_log(log if log.is_dir() else log.parent,
                                      by="`python -m services.replay RUN_DIR summary --write`")
        except RunDirError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(line, file=sys.stderr)
    s = s or summarize(args.log)
    if args.json:
        print(json.dumps(s, indent=2))
    else:
        print(format_summary(s))
    if not args.no_plot and s["returns"]:
        log = Path(args.log)
        plot = Path(args.plot) if args.plot else (log if log.is_dir() else log.parent) / "replay_curve.png"
        if plot_summary(s, plot):
            print(f"plot: {plot}", file=sys.stderr)
    return 1 if s["log"]["lost"] else 0


def cmd_play(args) -> int:
    import signal

    from common.wire.transport import client_config, free_port, open_session, router_config, tcp_endpoint
    from services.replay.play import play

    from services.common.runtime import set_from_handler

    signer = None
    if args.credentials:
        from common.wire.auth import AuthError, SignAsSender, load_credential

        try:
            signer = SignAsSender(load_credential(args.credentials))
        except AuthError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: set_from_handler(stop))
    signal.signal(signal.SIGTERM, lambda *_: set_from_handler(stop))
    if args.connect:
        config = client_config(*args.connect.split(","))
        where = args.connect
    else:
        where = tcp_endpoint(args.port or free_port())
        config = router_config(where)
    with open_session(config) as session:
        print(f"zenoh endpoint: {where}", file=sys.stderr, flush=True)
        if args.start_delay > 0:
            stop.wait(args.start_delay)
        t = time.perf_counter()
        counts = play(args.log, session, speed=args.speed, kinds=tuple(k for k in args.kinds.split(",") if k),
                      stop=stop, signer=signer)
        time.sleep(0.2)  # let BLOCK queues drain before closing
    total = sum(counts.values())
    print(f"published {total} records in {time.perf_counter() - t:.2f} s: {counts}", file=sys.stderr)
    return 130 if stop.is_set() else 0


def cmd_retrain(args) -> int:
    if args.screen_delay or args.screen_credit:
        return cmd_heldout(args)
    from services.replay.retrain import retrain

    try:
        result = retrain(args.log, args.learner)
    except ValueError as exc:
        print(f"cannot retrain: {exc}", file=sys.stderr)
        return 2
    print(result.report())
    if args.save:
        import safetensors.numpy

        safetensors.numpy.save_file(result.weights, args.save)
        print(f"retrained weights: {args.save}", file=sys.stderr)
    if not result.compared:
        return 2
    return 0 if result.identical and result.outcomes_match and not result.missing_inputs else 1


def cmd_heldout(args) -> int:
    """retrain with credit settings: each setting's held-out log-likelihood of the person's presses."""
    from services.replay.heldout import compare_settings, format_scores

    try:
        scores = compare_settings(args.log, args.screen_delay or ["learned"], args.screen_credit or ["onset"],
                                  args.fit_share, args.teacher, args.folds)
    except ValueError as exc:
        print(f"cannot score: {exc}", file=sys.stderr)
        return 2
    print(json.dumps([dataclasses.asdict(s) for s in scores], indent=1) if args.json else format_scores(scores))
    return 0


def cmd_size(args) -> int:
    from services.replay.size import format_size, log_size

    s = log_size(args.log)
    print(json.dumps(s, indent=2) if args.json else format_size(s))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.replay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", help="session.mcap (or a run directory); later segments are read too")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("summary", help="counts, returns, plot")
    p.add_argument("--json", action="store_true", help="print the whole summary as JSON")
    p.add_argument("--plot", help="learning-curve PNG (default: replay_curve.png beside the log)")
    p.add_argument("--no-plot", action="store_true", help="no plot")
    p.add_argument("--write", action="store_true",
                   help="finish a run whose launcher was killed (summary.json still 'running'): write its "
                        "summary.json and learning_curve.png from the log, outcome 'interrupted'")
    p = sub.add_parser("play", help="re-publish over Zenoh")
    p.add_argument("--connect", help="router endpoint(s) to publish through (default: run an embedded router)")
    p.add_argument("--port", type=int, default=0, help="embedded router port (0 = a free one)")
    p.add_argument("--speed", type=float, default=1.0, help="pace multiplier; 0 = as fast as possible")
    p.add_argument("--kinds", default="", help="only these key kinds, comma-separated (e.g. step,feedback)")
    p.add_argument("--start-delay", type=float, default=1.0, help="seconds to wait before publishing")
    p.add_argument("--credentials", help="a service credential of the run (python -m services credentials): each "
                                         "record is signed as its original sender; without one, receivers drop them")
    p = sub.add_parser("retrain", help="fresh learner on the recorded inputs; compare final weights")
    p.add_argument("--learner", help="learner incarnation (default: the last one in the log)")
    p.add_argument("--save", help="write the retrained final weights to this safetensors file")
    p.add_argument("--screen-delay", action="append", metavar="SPEC",
                   help="instead: score this credit setting's delay (learned, learned:PRIOR, uniform:LOW,HIGH, "
                        "NAME:ARGS; repeat to compare) by how well it predicts the presses it was not fitted on")
    p.add_argument("--screen-credit", action="append", choices=REFERENCES,
                   help="with --screen-delay: a step's time is its onset or its interval (repeat to compare both)")
    p.add_argument("--fit-share", type=float, default=0.7,
                   help="the earliest share of each person's presses that fits a setting; the rest are scored")
    p.add_argument("--folds", type=int, default=0,
                   help="instead of one split: forward chaining over K blocks of presses in time (block k scored by "
                        "a fit on the blocks before it)")
    p.add_argument("--teacher", help="only this teacher's presses (default: every console teacher's)")
    p.add_argument("--json", action="store_true", help="the scores as JSON")
    p = sub.add_parser("size", help="bytes per 1,000 steps and per topic")
    p.add_argument("--json", action="store_true", help="as JSON")
    args = parser.parse_args(argv)
    warnings.showwarning = _warn_to_stderr
    problem = no_log_here(Path(args.log))
    if problem:
        print(f"error: {args.log}: {problem}", file=sys.stderr)
        return 2
    from common.logs.mcap_log import NotMcapError

    try:
        return {"summary": cmd_summary, "play": cmd_play, "retrain": cmd_retrain,
                "size": cmd_size}[args.command](args)
    except NotMcapError as e:  # a video, a random file: say so in one line
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (FileNotFoundError, PermissionError, IsADirectoryError) as e:
        print(f"error: {e.filename or args.log}: {e.strerror or e}", file=sys.stderr)
        return 2


def no_log_here(path: Path) -> str | None:
    """Why there is no log to read at `path` (one line), or None."""
    if not path.exists():
        return "no such file or directory"
    if path.is_dir():
        if not (path / "session.mcap").is_file():
            return "a directory without a session.mcap (give a log file or a run directory)"
        path = path / "session.mcap"
    if not path.is_file():
        return "not a regular file"
    if path.stat().st_size == 0:
        return "an empty file (0 bytes): nothing was recorded"
    return None


def cli(argv: list[str] | None = None) -> int:
    return main(argv)


if __name__ == "__main__":
    sys.exit(cli())
