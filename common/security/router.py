"""A secured router process and the command line (``python -m common.security``)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

from common.security.certs import init
from common.security.config import (DEFAULT_PORT, SECURITY_FILE, SecurityConfig, SecurityError, load_security,
                                    tls_endpoint)
from common.security.zenoh_config import router_config_dict, router_config_for
from common.wire.transport import LOOPBACK

# -- a secured router process ----------------------------------------------------------------------------------

def run_secured_router(security: SecurityConfig, port: int | None = None, *, host: str | None = None,
                       stop: threading.Event | None = None) -> None:
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m common.security",
                                     description="TLS + user/password + access control for multi-machine runs")
    sub = parser.add_subparsers(dest="cmd", required=True)
    i = sub.add_parser("init", help="write a CA, a router certificate, credentials and security.json into DIR")
    i.add_argument("dir")
    i.add_argument("--teachers", default="", help="comma-separated teacher usernames (= their teacher_id)")
    i.add_argument("--hosts", default="", help="comma-separated extra names/IPs of the router machine for its "
                                               "certificate (localhost and 127.0.0.1 are always in)")
    i.add_argument("--router-host", default=LOOPBACK, help="the host clients dial (default 127.0.0.1)")
    i.add_argument("--port", type=int, default=DEFAULT_PORT)
    i.add_argument("--run", default="*", help="restrict all access to this run name (default: any run)")
    i.add_argument("--no-perception", action="store_true", help="no perception identity")
    i.add_argument("--days", type=int, default=365, help="certificate validity")
    r = sub.add_parser("router", help="run the secured router (prints 'ready <endpoint> <zid>')")
    r.add_argument("--security", required=True, help="the router machine's security.json")
    r.add_argument("--port", type=int, help="default: the port in security.json")
    r.add_argument("--host", help="listen address (default: router_host in security.json; 0.0.0.0 for all)")
    z = sub.add_parser("zenohd-config", help="print the router config as JSON (for zenohd -c)")
    z.add_argument("--security", required=True)
    z.add_argument("--port", type=int)
    z.add_argument("--host")
    args = parser.parse_args(argv)
    try:
        if args.cmd == "init":
            split = lambda s: [x.strip() for x in s.split(",") if x.strip()]  # noqa: E731
            sec = init(args.dir, split(args.teachers), hosts=split(args.hosts), router_host=args.router_host,
                       port=args.port, run=args.run, perception=None if args.no_perception else "perception",
                       days=args.days)
            print(f"wrote {Path(args.dir) / SECURITY_FILE} (router machine) and {Path(args.dir) / 'clients'}/<user>/ "
                  f"for {', '.join(sec.usernames())}")
            return 0
        sec = load_security(args.security)
        if args.cmd == "zenohd-config":
            print(json.dumps(router_config_dict(sec, args.port, host=args.host), indent=2))
            return 0
        run_secured_router(sec, args.port, host=args.host)
        return 0
    except SecurityError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
