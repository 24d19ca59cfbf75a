"""A secured router process and the commands of ``python -m services security init|router|zenohd-config``."""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zenoh

from common.config import option
from common.security.certs import init
from common.security.config import (
    DEFAULT_PORT,
    SECURITY_FILE,
    SecurityConfig,
    SecurityError,
    load_security,
    tls_endpoint,
)
from common.security.zenoh_config import router_config_dict, router_config_for
from common.wire.transport import LOOPBACK

# -- a secured router process ----------------------------------------------------------------------------------


def run_secured_router(
    security: SecurityConfig, port: int | None = None, *, host: str | None = None, stop: threading.Event | None = None
) -> None:
    """Run the secured router until ``stop`` is set or SIGTERM/SIGINT (main thread); prints
    ``ready <endpoint> <zid>`` once listening."""
    stop = stop or threading.Event()
    signalled: list[int] = []
    if threading.current_thread() is threading.main_thread():
        # The handler only appends to a list: calling stop.set() there can deadlock, because the signal may
        # arrive while the main thread holds the Event's lock inside stop.wait() (seen here: a router that
        # ignored SIGTERM forever, its main thread stuck in Event.set under Event.wait).
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda signum, _frame: signalled.append(signum))
    endpoint = tls_endpoint(security.port if port is None else port, security.router_host if host is None else host)
    session = zenoh.open(router_config_for(security, port, host=host))
    try:
        print(f"ready {endpoint} {session.zid()}", flush=True)
        while not signalled and not stop.is_set():  # is_set() takes no lock
            time.sleep(0.1)
    finally:
        session.close()


def _names(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


@dataclass(frozen=True)
class SecurityInitConfig:
    """Write a CA, a router certificate, credentials and security.json into DIR (TLS + user/password + access
    control for a run across machines; docs/security.md)."""

    dir: str = option("", "output directory", positional=True)
    teachers: str = option("", "comma-separated teacher usernames (= their teacher_id)")
    hosts: str = option(
        "",
        "comma-separated extra names/IPs of the router machine for its certificate "
        "(localhost and 127.0.0.1 are always in)",
    )
    router_host: str = option(LOOPBACK, "the host clients dial")
    port: int = option(DEFAULT_PORT, "the router's port")
    run: str = option("*", "restrict all access to this run name (*: any run)")
    perception: bool = option(True, "make a perception identity")
    days: int = option(365, "certificate validity in days")


@dataclass(frozen=True)
class SecuredRouterConfig:
    """Run the secured router (prints 'ready <endpoint> <zid>'); `zenohd-config` prints its config as JSON for
    zenohd -c instead."""

    security: str = option("", "the router machine's security.json (python -m services security init)")
    port: int | None = option(None, "listen port (default: the port in security.json)")
    host: str | None = option(None, "listen address (default: router_host in security.json; 0.0.0.0 for all)")

    def __post_init__(self):
        if not self.security:
            raise ValueError("--security is required")


def security_init(args: SecurityInitConfig) -> int:
    try:
        sec = init(
            args.dir,
            _names(args.teachers),
            hosts=_names(args.hosts),
            router_host=args.router_host,
            port=args.port,
            run=args.run,
            perception="perception" if args.perception else None,
            days=args.days,
        )
    except SecurityError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(
        f"wrote {Path(args.dir) / SECURITY_FILE} (router machine) and {Path(args.dir) / 'clients'}/<user>/ "
        f"for {', '.join(sec.usernames())}"
    )
    return 0


def secured_router(args: SecuredRouterConfig, print_config: bool = False) -> int:
    try:
        sec = load_security(args.security)
        if print_config:
            print(json.dumps(router_config_dict(sec, args.port, host=args.host), indent=2))
            return 0
        run_secured_router(sec, args.port, host=args.host)
        return 0
    except SecurityError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def zenohd_config(args: SecuredRouterConfig) -> int:
    return secured_router(args, print_config=True)
