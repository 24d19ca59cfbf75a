"""python -m services.replay {summary, play, retrain, size} LOG.mcap: a recorded session, offline.

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

LOG may also come before the command (`python -m services.replay LOG summary`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

from common.config import Command, option
from common.core.delay_model import REFERENCES


@dataclass(frozen=True)
class LogConfig:
    log: str = option("", "session.mcap (or a run directory); later segments are read too", positional=True)


@dataclass(frozen=True)
class SummaryConfig(LogConfig):
    """Counts, losses, what became of every feedback, per-episode returns, learning-curve plot."""

    json: bool = option(False, "print the whole summary as JSON")
    plot: str | None = option(None, "learning-curve PNG (default: replay_curve.png beside the log)")
    no_plot: bool = option(False, "no plot")
    write: bool = option(
        False,
        "finish a run whose launcher was killed (summary.json still 'running'): write its "
        "summary.json and learning_curve.png from the log, outcome 'interrupted'",
    )


@dataclass(frozen=True)
class PlayConfig(LogConfig):
    """Re-publish the session over Zenoh at the recorded pace (or faster)."""

    connect: str | None = option(None, "router endpoint(s) to publish through (default: run an embedded router)")
    port: int = option(0, "embedded router port (0 = a free one)")
    speed: float = option(1.0, "pace multiplier; 0 = as fast as possible")
    kinds: str = option("", "only these key kinds, comma-separated (e.g. step,feedback)")
    start_delay: float = option(1.0, "seconds to wait before publishing")
    credentials: str | None = option(
        None,
        "a service credential of the run (python -m services credentials): each "
        "record is signed as its original sender; without one, receivers drop them",
    )


@dataclass(frozen=True)
class RetrainConfig(LogConfig):
    """Feed a fresh learner the recorded inputs in the recorded order; say whether its final weights equal the live
    learner's bit for bit (exit 0 if they do, 1 if not, 2 if the log cannot tell)."""

    learner: str | None = option(None, "learner incarnation (default: the last one in the log)")
    save: str | None = option(None, "write the retrained final weights to this safetensors file")
    screen_delay: tuple[str, ...] = option(
        (),
        "instead: score this credit setting's delay (learned, learned:PRIOR, "
        "uniform:LOW,HIGH, NAME:ARGS; repeat to compare) by how well it "
        "predicts the presses it was not fitted on",
        nargs="+",
        metavar="SPEC",
    )
    screen_credit: tuple[str, ...] = option(
        (),
        "with --screen-delay: a step's time is its onset or its interval (repeat to compare both)",
        nargs="+",
        choices=REFERENCES,
    )
    fit_share: float = option(
        0.7, "the earliest share of each person's presses that fits a setting; the rest are scored"
    )
    folds: int = option(
        0,
        "instead of one split: forward chaining over K blocks of presses in time (block k scored "
        "by a fit on the blocks before it)",
    )
    teacher: str | None = option(None, "only this teacher's presses (default: every console teacher's)")
    json: bool = option(False, "the scores as JSON")


@dataclass(frozen=True)
class SizeConfig(LogConfig):
    """Bytes per 1,000 steps, and per topic."""

    json: bool = option(False, "as JSON")


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
            s, line = finish_from_log(
                log if log.is_dir() else log.parent, by="`python -m services.replay summary RUN_DIR --write`"
            )
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
    import contextlib
    import signal

    import zenoh

    from common.wire.transport import PortInUse, client_config, open_listening, router_config, tcp_endpoint
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
        session, where = zenoh.open(client_config(*args.connect.split(","))), args.connect
    else:
        try:
            session, port = open_listening(lambda p: router_config(tcp_endpoint(p)), args.port or 0)
        except PortInUse as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        where = tcp_endpoint(port)
    with contextlib.closing(session):
        print(f"zenoh endpoint: {where}", file=sys.stderr, flush=True)
        if args.start_delay > 0:
            stop.wait(args.start_delay)
        t = time.perf_counter()
        counts = play(
            args.log,
            session,
            speed=args.speed,
            kinds=tuple(k for k in args.kinds.split(",") if k),
            stop=stop,
            signer=signer,
        )
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
        scores = compare_settings(
            args.log,
            list(args.screen_delay) or ["learned"],
            list(args.screen_credit) or ["onset"],
            args.fit_share,
            args.teacher,
            args.folds,
        )
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


def _guarded(run):
    """No log to read, or a file that is not MCAP (a video, a random file): one line, exit 2."""

    def guarded(args) -> int:
        from common.logs.mcap_log import NotMcapError

        warnings.showwarning = _warn_to_stderr
        problem = no_log_here(Path(args.log))
        if problem:
            print(f"error: {args.log}: {problem}", file=sys.stderr)
            return 2
        try:
            return run(args)
        except NotMcapError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        except (FileNotFoundError, PermissionError, IsADirectoryError) as e:
            print(f"error: {e.filename or args.log}: {e.strerror or e}", file=sys.stderr)
            return 2

    return guarded


COMMANDS = {
    "summary": Command(SummaryConfig, _guarded(cmd_summary)),
    "play": Command(PlayConfig, _guarded(cmd_play)),
    "retrain": Command(RetrainConfig, _guarded(cmd_retrain)),
    "size": Command(SizeConfig, _guarded(cmd_size)),
}


def cli(argv: list[str] | None = None) -> int:
    from common.config import run_commands

    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) > 1 and argv[0] not in COMMANDS and argv[1] in COMMANDS:  # the log first, as before
        argv[0], argv[1] = argv[1], argv[0]
    return run_commands("python -m services.replay", __doc__, COMMANDS, argv)
