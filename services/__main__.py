"""python -m services {up, bench, chaos}: the live system on this machine.

  up     start an embedded Zenoh router and every service as its own process; progress; summary
  bench  throughput and latency figures of the live system on this machine (not a test)
  chaos  SIGKILL every service in turn during a run: losses, recovery times, rejected inputs (docs/faults.md)
  bench-compare  steps/s of this checkout against another (e.g. a worktree of an earlier commit), interleaved
  credentials  a run's credential files for services started by hand, or one more teacher's (docs/security.md)

Each service also runs on its own: python -m services.{actor,teacher,learner,recorder} --help, and
python -m services.replay --help for logs.
"""
from __future__ import annotations

import argparse
import sys

from common.config import ConfigParser, add_config_arguments, config_from_namespace


def main(argv: list[str] | None = None) -> int:
    from services.bench import BenchConfig, bench
    from services.bench_compare import BenchCompareConfig, bench_compare
    from services.chaos import ChaosConfig, chaos
    from services.credentials import CredentialsConfig, credentials
    from services.launcher import UpConfig, up

    parser = ConfigParser(prog="python -m services", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {"up": (UpConfig, up), "bench": (BenchConfig, bench), "chaos": (ChaosConfig, chaos),
                "credentials": (CredentialsConfig, credentials), "bench-compare": (BenchCompareConfig, bench_compare)}
    parsers = {}
    for name, (cls, _) in commands.items():
        doc = (cls.__doc__ or "").strip()
        parsers[name] = p = sub.add_parser(name, help=doc.split("\n")[0], description=doc)
        add_config_arguments(p, cls)
    args = parser.parse_args(argv)
    cls, fn = commands[args.command]
    try:
        config = config_from_namespace(cls, args)
    except (ValueError, OSError) as exc:
        parsers[args.command].error(str(exc))
    return fn(config)


if __name__ == "__main__":
    sys.exit(main())
