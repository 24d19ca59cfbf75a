"""The settings every live service has (`ServiceConfig`: run name, router, launcher link, statuses, security),
the base of each service's config in services/common/config.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.config import option
from common.protocol import validate_name

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
CLOCKS = ("steps", "wall")


def _check_name(value: str, what: str) -> None:
    try:
        validate_name(value, what)
    except Exception as exc:  # ProtocolError -> ValueError for the CLI
        raise ValueError(f"{what}: {exc}") from None


@dataclass(frozen=True)
class ServiceConfig:
    """Settings every service has."""

    run: str = option("live", "run name: the second chunk of every key (hitl/<run>/...)")
    connect: tuple[str, ...] = option((DEFAULT_ENDPOINT,), "Zenoh router endpoint(s) to connect to, comma-separated")
    parent_pid: int | None = option(None, "exit when this process is gone (the launcher passes its pid)")
    stats_out: str | None = option(None, "write final counters and latency samples to this JSON file at exit")
    # Every status is signed, sent through the router and decoded by the recorder, the launcher and the console:
    # at 2 s the six processes' statuses were a third of what a paced run's services received. The launcher's
    # hang rule waits 60 s (--hang-timeout) for one: every 5 s still gives it twelve.
    status_period: float = option(5.0, "seconds between ServiceStatus messages")
    connect_timeout: float = option(15.0, "seconds to keep trying to reach the router at start")
    security: str | None = option(
        None,
        "security.json of this machine (common/security.py: TLS, user/password, "
        "access control); connect to the secured router as this service's identity",
    )
    credentials: str | None = option(
        None,
        "this service's credential file (common/wire/auth.py): signs what it publishes, "
        "checks what it receives; the launcher writes one per service, "
        "`python -m services credentials` for services started by hand",
    )

    def __post_init__(self):
        _check_name(self.run, "run")
        if not self.connect:
            raise ValueError("connect: at least one endpoint")
        for name in ("status_period", "connect_timeout"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name.replace('_', '-')} must be positive, got {v}")
