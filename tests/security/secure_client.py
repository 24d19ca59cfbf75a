"""A client process for the access-control tests, always run as its own process.

``sub``: subscribe with a security.json identity, print ``subscribed``, then one JSON line per sample
(``{"key", "payload"}``) until stdin closes.

``pub``: open a session (optionally with a wrong password, an unknown user, no credentials, plain tcp or
another CA), put each ``--put KEY=PAYLOAD`` in order through one session, and print one JSON line:
``{"opened": true, "puts": [{"key", "matching"}]}`` or ``{"opened": false, "error": "..."}``.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import zenoh  # noqa: E402

from common.config import option, parse_config  # noqa: E402
from common.security import (
    client_config_for,
    client_settings,
    load_security,  # noqa: E402
    SecurityConfig,
)
from common.wire.transport import make_config, open_session, wait_for_matching  # noqa: E402


def sub(args: ClientArgs) -> int:
    sec = load_security(args.security)
    samples: queue.Queue = queue.Queue()
    closed = threading.Event()

    def watch_stdin() -> None:
        sys.stdin.read()
        closed.set()

    threading.Thread(target=watch_stdin, daemon=True).start()
    with open_session(
        client_config_for(
            sec, sec.role_of(args.user), args.endpoint, teacher=args.user if args.user in sec.teachers else None
        )
    ) as session:
        subscriber = session.declare_subscriber(
            args.key, lambda s: samples.put((str(s.key_expr), s.payload.to_bytes()))
        )
        try:
            print("subscribed", flush=True)
            while not closed.is_set():
                try:
                    key, payload = samples.get(timeout=0.1)
                except queue.Empty:
                    continue
                print(json.dumps({"key": key, "payload": payload.decode("utf-8", "replace")}), flush=True)
        finally:
            subscriber.undeclare()
    return 0


def client_config(sec: SecurityConfig, args: ClientArgs) -> zenoh.Config:
    if args.tcp:
        endpoint = f"tcp/127.0.0.1:{args.tcp}"
    else:
        endpoint = sec.endpoint(args.endpoint)
    config = make_config("client", connect=[endpoint], connect_timeout=args.connect_timeout)
    if args.no_auth:
        settings = {"transport/link/tls/root_ca_certificate": str(sec.path(sec.ca_cert))}
    elif args.password is not None:  # any user, any password
        settings = {
            "transport/link/tls/root_ca_certificate": str(sec.path(sec.ca_cert)),
            "transport/auth/usrpwd/user": args.user,
            "transport/auth/usrpwd/password": args.password,
        }
    else:
        settings = client_settings(sec, args.user)
    if args.ca:
        settings["transport/link/tls/root_ca_certificate"] = args.ca
    if not args.tcp:
        settings["transport/link/protocols"] = ["tls"]
    for path, value in settings.items():
        config.insert_json5(path, json.dumps(value))
    return config


def pub(args: ClientArgs) -> int:
    sec = load_security(args.security)
    try:
        session = zenoh.open(client_config(sec, args))
    except Exception as e:  # zenoh.ZError: refused or unreachable
        print(json.dumps({"opened": False, "error": str(e)[:300]}), flush=True)
        return 0
    puts = []
    try:
        for spec in args.put:
            key, _, payload = spec.partition("=")
            publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            matching = wait_for_matching(publisher, args.match_timeout)
            result = publisher.put(payload.encode())
            puts.append({"key": key, "matching": matching, "result": repr(result)})
        time.sleep(0.3)  # let the transmission queue empty before closing
    finally:
        session.close()
    print(json.dumps({"opened": True, "puts": puts}), flush=True)
    return 0


@dataclass(frozen=True)
class ClientArgs:
    """A subscriber or publisher with a security.json identity (or a wrong one), for the access-control tests."""

    cmd: str = option("sub", "subscribe or publish", positional=True, choices=("sub", "pub"))
    security: str = option("", "the identity's security.json")
    endpoint: str = option("", "tls/host:port")
    user: str = option("", "the identity's user name")
    key: str = option("hitl/**", "what a subscriber subscribes to")
    put: tuple[str, ...] = option((), "KEY=PAYLOAD to publish, in order; repeatable", nargs="+")
    password: str | None = option(None, "log in as --user with this password (no lookup)")
    no_auth: bool = option(False, "no user/password at all")
    tcp: int | None = option(None, "dial plain tcp/127.0.0.1:PORT instead")
    ca: str | None = option(None, "trust this CA certificate instead")
    connect_timeout: float = option(5.0, "seconds to connect")
    match_timeout: float = option(5.0, "seconds to wait for a matching subscriber before each put")


def main() -> int:
    args = parse_config(ClientArgs, prog="secure_client.py")
    return sub(args) if args.cmd == "sub" else pub(args)


if __name__ == "__main__":
    sys.exit(main())
