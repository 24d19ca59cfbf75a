"""python -m services COMMAND: the live system on this machine, and its tools.

Each service also runs on its own: python -m services.{actor,teacher,learner,recorder,perception,console,
foxglove} --help, and python -m services.replay --help for logs. Comparisons of two checkouts:
python -m experiments bench-compare --what live.
"""

from __future__ import annotations

import os
import sys

# The services compute on one BLAS thread (`apply_torch_threads`). Said before numpy is imported, OpenBLAS never
# starts its thread pool: 0.1 s less CPU at each process's start (numpy's import alone, 20 runs: 0.28 -> 0.18 s),
# and 7 % less for a tiny run's whole tree (`services up --episodes 2 --max-steps 30
# --curve false`, 8 runs each, alternating: 3.17 -> 2.94 s).
# The launcher passes it on to the services it starts (`child_env`).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from common.config import Command, run_commands  # noqa: E402


def commands() -> dict:
    from common.protocol._cli import ProtocolConfig, protocol_main
    from common.security.router import SecuredRouterConfig, SecurityInitConfig, secured_router, security_init
    from common.security.router import zenohd_config
    from common.wire.auth_bench import AuthBenchConfig, bench_main
    from common.wire.transport import RouterConfig, router_main
    from services.bench import BenchConfig, bench
    from services.chaos import ChaosConfig, chaos
    from services.credentials import CredentialsConfig, credentials
    from services.flood import FloodConfig, main as flood
    from services.launcher import UpConfig, up
    from services.launcher.compose import ComposeConfig, compose

    return {
        "up": Command(UpConfig, up),
        "bench": Command(BenchConfig, bench),
        "chaos": Command(ChaosConfig, chaos),
        "flood": Command(FloodConfig, flood),
        "credentials": Command(CredentialsConfig, credentials),
        "security": {
            "": "TLS + user/password + access control for runs across machines (docs/security.md)",
            "init": Command(SecurityInitConfig, security_init),
            "router": Command(SecuredRouterConfig, secured_router),
            "zenohd-config": Command(
                SecuredRouterConfig, zenohd_config, "print the secured router's config as JSON (for zenohd -c)"
            ),
        },
        "router": Command(RouterConfig, router_main),
        "protocol": Command(ProtocolConfig, protocol_main),
        "auth-bench": Command(AuthBenchConfig, bench_main),
        "compose": Command(ComposeConfig, compose),
    }


def main(argv: list[str] | None = None) -> int:
    return run_commands(
        "python -m services",
        __doc__,
        commands(),
        argv,
        moved={"bench-compare": "python -m experiments bench-compare --what live"},
    )


if __name__ == "__main__":
    sys.exit(main())
