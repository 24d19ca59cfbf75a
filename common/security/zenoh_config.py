"""Zenoh configs of the secured router and its clients (TLS, user/password, access control)."""

from __future__ import annotations

import json
from typing import Any

import zenoh

from common.security.access import access_control
from common.security.config import DEFAULT_PORT, SecurityConfig, SecurityError, tls_endpoint  # noqa: F401
from common.wire.transport import DEFAULT_CONNECT_TIMEOUT, make_config

# -- zenoh configs ---------------------------------------------------------------------------------------------


def router_settings(security: SecurityConfig) -> dict[str, Any]:
    """The secured parts of the router's zenoh config, as ``{path: value}`` for ``Config.insert_json5``.
    Merged with ``mode``/``listen`` this is also a zenohd config (see :func:`router_config_dict`)."""
    for name in ("router_cert", "router_key", "credentials_file"):
        p = security.path(getattr(security, name))
        if not p.is_file():
            raise SecurityError(f"{name}: {p} is not a file")
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls/listen_certificate": str(security.path(security.router_cert)),
        "transport/link/tls/listen_private_key": str(security.path(security.router_key)),
        "transport/auth/usrpwd/dictionary_file": str(security.path(security.credentials_file)),
        "access_control": access_control(security),
    }


def client_settings(security: SecurityConfig, username: str) -> dict[str, Any]:
    """The secured parts of a client's zenoh config: trust the run's CA, TLS only, log in as ``username``."""
    ca = security.path(security.ca_cert)
    if not ca.is_file():
        raise SecurityError(f"ca_cert: {ca} is not a file")
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls/root_ca_certificate": str(ca),
        "transport/auth/usrpwd/user": username,
        "transport/auth/usrpwd/password": security.password(username),
    }


def _apply(config: zenoh.Config, settings: dict[str, Any]) -> zenoh.Config:
    for path, value in settings.items():
        config.insert_json5(path, json.dumps(value))
    return config


def router_config_for(
    security: SecurityConfig, port: int | None = None, *, host: str | None = None, timestamping: bool = True
) -> zenoh.Config:
    """A secured router (a Python session in router mode) listening on ``tls/<host>:<port>`` only.

    ``host`` defaults to ``security.router_host`` (127.0.0.1 unless configured); use ``"0.0.0.0"`` or the
    machine's address to accept other machines. ``port`` defaults to ``security.port``."""
    endpoint = tls_endpoint(security.port if port is None else port, security.router_host if host is None else host)
    return _apply(make_config("router", listen=[endpoint], timestamping=timestamping), router_settings(security))


def client_config_for(
    security: SecurityConfig,
    role: str,
    endpoint: int | str | None = None,
    *,
    teacher: str | None = None,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
    timestamping: bool = True,
) -> zenoh.Config:
    """A secured client of the router for the service ``role`` (learner, actor, recorder, perception, or
    teacher with ``teacher=<username>``). ``endpoint``: None (the configured router), a port on the
    configured router host, or a ``tls/host:port`` endpoint; a ``tcp/`` endpoint is refused."""
    username = security.username(role, teacher)
    config = make_config(
        "client", connect=[security.endpoint(endpoint)], connect_timeout=connect_timeout, timestamping=timestamping
    )
    return _apply(config, client_settings(security, username))


def router_config_dict(security: SecurityConfig, port: int | None = None, *, host: str | None = None) -> dict:
    """The router config as a nested dict (JSON): what ``zenohd -c FILE`` would take."""
    out: dict[str, Any] = {
        "mode": "router",
        "listen": {
            "endpoints": [
                tls_endpoint(security.port if port is None else port, security.router_host if host is None else host)
            ]
        },
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "timestamping": {"enabled": True},
    }
    for path, value in router_settings(security).items():
        node = out
        *parents, leaf = path.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out
