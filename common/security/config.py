"""The secured deployment's configuration: who is who, where the secrets are (``security.json``)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
from pathlib import Path
from typing import Any

from common.protocol import teacher_service_name
from common.security.files import write_private
from common.wire.transport import LOOPBACK

DEFAULT_PORT = 7447
SECURITY_FILE = "security.json"
CREDENTIALS_FILE = "credentials.txt"
CA_CERT, CA_KEY = "ca.pem", "ca.key"
ROUTER_CERT, ROUTER_KEY = "router.pem", "router.key"

#: Usernames become zenoh dictionary entries (``user:password``, so no ``:``) and, for teachers, the
#: ``teacher_id`` chunk of the feedback key (common.protocol's NAME_PATTERN without ``:``).
USERNAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
_USERNAME_RE = re.compile(USERNAME_PATTERN[:-1] + r"\Z")

#: The single-identity roles of a secured deployment (a teacher's username is its teacher id). What each may
#: publish is the protocol's table (common.protocol.PUBLISHES), for the identity's service name.
SERVICE_ROLES = ("learner", "actor", "recorder", "perception")
ROLES = SERVICE_ROLES + ("teacher",)


class SecurityError(ValueError):
    """A security configuration that cannot be used (missing identity, file, password, bad name)."""


def validate_username(name: str, what: str = "username") -> str:
    if not isinstance(name, str) or not _USERNAME_RE.match(name):
        raise SecurityError(f"{what}: {name!r} does not match {USERNAME_PATTERN}")
    return name


# -- the configuration -----------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SecurityConfig:
    """Where the secrets are and who is who. Stored as JSON (``security.json``) with paths relative to
    the JSON file's folder; :func:`load_security` resolves them against ``base_dir``.

    Router machine: ``router_cert``, ``router_key`` and a ``credentials_file`` with every user's line.
    Client machine: no router key; a ``credentials_file`` with at least the line of the identity it runs.
    """

    ca_cert: str  # PEM certificate of the run's CA: clients verify the router against it
    credentials_file: str  # ``user:password`` lines (zenoh's usrpwd dictionary format)
    router_cert: str | None = None  # PEM certificate the router presents (router machine only)
    router_key: str | None = None  # its PKCS#8 private key (router machine only)
    learner: str = "learner"  # username of each identity
    actor: str = "actor"
    recorder: str = "recorder"
    perception: str | None = "perception"  # None: no perception identity
    teachers: tuple[str, ...] = ()  # teacher usernames; each is also its teacher_id in the feedback key
    run: str = "*"  # restrict every rule to hitl/<run>/...; "*" allows any run name
    router_host: str = LOOPBACK  # host the clients dial (must be in the router certificate's SANs)
    port: int = DEFAULT_PORT  # router port
    base_dir: str = "."  # relative paths above are resolved against this (the JSON file's folder)

    def __post_init__(self) -> None:
        object.__setattr__(self, "teachers", tuple(self.teachers))
        for role in SERVICE_ROLES:
            name = getattr(self, role)
            if name is not None:
                validate_username(name, role)
        for t in self.teachers:
            validate_username(t, "teacher")
        users = self.usernames()
        if len(set(users)) != len(users):
            raise SecurityError(f"identities must be distinct usernames: {users}")
        if self.run != "*":
            validate_username(self.run, "run")

    # identities
    def usernames(self) -> list[str]:
        """Every identity, services first, then teachers."""
        return [n for n in (getattr(self, r) for r in SERVICE_ROLES) if n is not None] + list(self.teachers)

    def username(self, role: str, teacher: str | None = None) -> str:
        """The username a service of ``role`` connects as (for ``"teacher"``: ``teacher``, which must be
        one of :attr:`teachers`)."""
        if role == "teacher":
            if teacher is None:
                raise SecurityError("role 'teacher' needs teacher=<one of the teachers>")
            if teacher not in self.teachers:
                raise SecurityError(f"teacher {teacher!r} is not one of {list(self.teachers)}")
            return teacher
        if role not in SERVICE_ROLES:
            raise SecurityError(f"role {role!r}: one of {ROLES}")
        name = getattr(self, role)
        if name is None:
            raise SecurityError(f"no {role} identity is configured")
        return name

    def role_of(self, username: str) -> str:
        for role in SERVICE_ROLES:
            if getattr(self, role) == username:
                return role
        if username in self.teachers:
            return "teacher"
        raise SecurityError(f"unknown user {username!r}")

    def service_of(self, username: str) -> str:
        """The service name (protocol identity) ``username`` runs as: ``teacher.<username>`` for a teacher."""
        role = self.role_of(username)
        return teacher_service_name(username) if role == "teacher" else role

    # files
    def path(self, name: str | None) -> Path:
        if name is None:
            raise SecurityError("this security config has no such file (router files live on the router machine)")
        p = Path(name)
        return p if p.is_absolute() else Path(self.base_dir) / p

    def password(self, username: str) -> str:
        """``username``'s password, read from :attr:`credentials_file`."""
        creds = read_credentials(self.path(self.credentials_file))
        if username not in creds:
            raise SecurityError(f"no password for {username!r} in {self.path(self.credentials_file)}")
        return creds[username]

    def endpoint(self, port_or_endpoint: int | str | None = None) -> str:
        """``tls/<router_host>:<port>``, or the given port on router_host, or the given ``tls/`` endpoint."""
        if port_or_endpoint is None:
            port_or_endpoint = self.port
        if isinstance(port_or_endpoint, int):
            return tls_endpoint(port_or_endpoint, self.router_host)
        if not port_or_endpoint.startswith("tls/"):
            raise SecurityError(f"a secured client connects over tls/ only, not {port_or_endpoint!r}")
        return port_or_endpoint

    # JSON
    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("base_dir")
        d["teachers"] = list(self.teachers)
        return d

    def for_client(
        self, username: str, credentials_file: str = CREDENTIALS_FILE, ca_cert: str = CA_CERT
    ) -> SecurityConfig:
        """The copy a client machine gets: no router files, its own credentials file."""
        self.role_of(username)
        return dataclasses.replace(
            self, router_cert=None, router_key=None, ca_cert=ca_cert, credentials_file=credentials_file
        )


def load_security(path: str | os.PathLike) -> SecurityConfig:
    """Read a ``security.json``; relative paths in it are relative to its folder."""
    path = Path(path)
    data = json.loads(path.read_text())
    fields = {f.name for f in dataclasses.fields(SecurityConfig)} - {"base_dir"}
    unknown = set(data) - fields
    if unknown:
        raise SecurityError(f"{path}: unknown fields {sorted(unknown)}")
    data["teachers"] = tuple(data.get("teachers", ()))
    return SecurityConfig(**data, base_dir=str(path.resolve().parent))


def save_security(security: SecurityConfig, path: str | os.PathLike) -> Path:
    path = Path(path)
    path.write_text(json.dumps(security.to_json(), indent=2) + "\n")
    return path


def read_credentials(path: str | os.PathLike) -> dict[str, str]:
    """``user:password`` lines -> dict (blank lines skipped; zenoh accepts no comments)."""
    out: dict[str, str] = {}
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise SecurityError(f"{path}:{n}: expected user:password")
        out[user] = password
    return out


def write_credentials(path: str | os.PathLike, creds: dict[str, str]) -> Path:
    for user, password in creds.items():
        validate_username(user)
        if not password or any(c in password for c in ":\n\r"):
            raise SecurityError(f"password of {user!r} must be non-empty without ':' or newlines")
    return write_private(Path(path), "".join(f"{u}:{p}\n" for u, p in creds.items()).encode())


def tls_endpoint(port: int, host: str = LOOPBACK) -> str:
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"  # IPv6 literal
    return f"tls/{host}:{int(port)}"
