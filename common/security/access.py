"""The secured router's access rules, built from the protocol's table of who may publish what."""

from __future__ import annotations

from typing import Any
from collections.abc import Iterable

from common.protocol import ALIVE, ROOT, publish_patterns
from common.security.config import SecurityConfig, SecurityError

# -- access control --------------------------------------------------------------------------------------------


def publish_kinds(service: str) -> list[str]:
    """The protocol's publish rights of `service` as key tails for the router (`NAME+`: `NAME` and `NAME-$*`)."""
    out: list[str] = []
    for p in publish_patterns(service):
        out += [p[:-1], f"{p[:-1]}-$*"] if p.endswith("+") else [p]
    return out


def _keys(security: SecurityConfig, kinds: Iterable[str]) -> list[str]:
    return [f"{ROOT}/{security.run}/{k}" for k in kinds]


def _allow(rule_id: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> dict[str, Any]:
    """One `allow` rule of the router's access control."""
    return {"id": rule_id, "messages": messages, "flows": flows, "permission": "allow", "key_exprs": key_exprs}


def access_control(security: SecurityConfig) -> dict[str, Any]:
    """The router's ``access_control`` section: default deny; rules keyed by username.

    - ``read`` (every identity): ``declare_subscriber`` both ways (ingress: a client may subscribe;
      egress: a publisher learns that a subscriber exists, without which a zenoh 1.x client sends
      nothing) and egress ``put`` (the router forwards data to it) on ``hitl/<run>/**``.
    - ``publish-<user>``: ingress ``put`` on the keys its role may publish (:data:`PUBLISH`, plus
      ``common.protocol.PUBLISHES`` for its service name (``teacher.<user>`` for a teacher): its own
      ``status`` and ``log`` only, never another identity's).
    - liveliness: every identity may watch ``hitl/<run>/alive/**`` (subscriber, history query and its replies,
      tokens forwarded to it); ``alive-<user>`` lets it declare tokens only under its own service name
      (``alive/<service>`` and ``alive/<service>/<incarnation>``).

    Everything else (delete, queries, queryables, other tokens, other keys) falls to the default: deny.
    Subjects also require the ``tls`` link protocol, so a password alone over some other link is useless.
    """
    users = security.usernames()
    read_scope = f"{ROOT}/**" if security.run == "*" else f"{ROOT}/{security.run}/**"
    alive_scope = f"{ROOT}/*/{ALIVE}/**" if security.run == "*" else f"{ROOT}/{security.run}/{ALIVE}/**"
    rules: list[dict[str, Any]] = [
        _allow("read-subscribe", ["declare_subscriber"], ["ingress", "egress"], [read_scope]),
        _allow("read-receive", ["put"], ["egress"], [read_scope]),
        # Who is alive: anyone may watch the tokens (with history: a liveliness query and its replies).
        _allow(
            "alive-watch",
            ["declare_liveliness_subscriber", "liveliness_query", "liveliness_token", "reply"],
            ["egress"],
            [alive_scope],
        ),
        _allow("alive-ask", ["declare_liveliness_subscriber", "liveliness_query"], ["ingress"], [alive_scope]),
    ]
    subjects: list[dict[str, Any]] = [{"id": "everyone", "usernames": users, "link_protocols": ["tls"]}]
    policies: list[dict[str, Any]] = [
        {
            "id": "everyone-reads",
            "rules": ["read-subscribe", "read-receive", "alive-watch", "alive-ask"],
            "subjects": ["everyone"],
        }
    ]
    for user in users:
        service = security.service_of(user)
        rules.append(_allow(f"publish-{user}", ["put"], ["ingress"], _keys(security, publish_kinds(service))))
        alive = _keys(security, [f"{ALIVE}/{service}", f"{ALIVE}/{service}/*"])
        rules.append(_allow(f"alive-{user}", ["liveliness_token"], ["ingress"], alive))
        subjects.append({"id": f"user-{user}", "usernames": [user], "link_protocols": ["tls"]})
        policies.append(
            {"id": f"{user}-publishes", "rules": [f"publish-{user}", f"alive-{user}"], "subjects": [f"user-{user}"]}
        )
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def publish_keys(security: SecurityConfig, username: str) -> list[str]:
    """The key expressions ``username`` may put on (as the router's rules say)."""
    for rule in access_control(security)["rules"]:
        if rule["id"] == f"publish-{username}":
            return list(rule["key_exprs"])
    raise SecurityError(f"unknown user {username!r}")
