"""Secured Zenoh for multi-machine runs: TLS, user/password authentication and access control (issue 6).

By default every service listens and connects on 127.0.0.1 only (``common.transport``), so nobody else is
let in. To spread the services over several machines, run one secured router and connect every service to
it as a client:

- **TLS** (``tls/HOST:PORT``): the router presents a certificate signed by the run's own CA; every client
  checks it against that CA (``verify_name_on_connect``: the host the client dials must be in the
  certificate's SubjectAltName). Plain ``tcp/`` to the TLS port fails the handshake.
- **User/password** (``transport/auth/usrpwd``): the router holds the dictionary (``user:password`` lines);
  every client proves its own password (an HMAC over a nonce; the password never crosses the wire). No
  credentials, an unknown user or a wrong password: ``zenoh.open`` fails.
- **Access control** on the router (``access_control``, ``default_permission: "deny"``), keyed by username:
  only the learner may put ``hitl/<run>/weights``; teacher ``T`` only ``hitl/<run>/feedback/T``; the actor
  ``step``, ``episode`` and ``config``; perception ``camera/*`` and ``perception/*``; everybody
  ``status/*``. Every authenticated identity may subscribe to and receive ``hitl/<run>/**`` (so the recorder
  records everything). A denied put is dropped silently by the router: the publisher gets no error.

Use (see docs/security.md)::

    python -m common.security init DIR --teachers alice,bob [--hosts 192.168.1.10,router.lan]
    python -m common.security router --security DIR/security.json [--host 0.0.0.0] [--port 7447]

    sec = load_security("DIR/clients/learner/security.json")
    with open_session(client_config_for(sec, "learner")) as session: ...
    with open_session(client_config_for(sec, "teacher", teacher="alice")) as session: ...

``init`` writes ``DIR/`` for the router machine (CA key and certificate, router key and certificate, the
full credentials file, ``security.json``) and ``DIR/clients/<user>/`` for each identity (the CA
certificate, a credentials file holding that user's line only, a ``security.json``): copy that folder to
the machine that runs the service. Private keys and credentials are written mode 0600. Never commit them.

Facts measured here with eclipse-zenoh 1.10 (tests/security/test_access_control.py checks them):

- Keys that work: ``transport/link/tls/{root_ca_certificate, listen_certificate, listen_private_key}``,
  ``transport/auth/usrpwd/{user, password, dictionary_file}``, ``transport/link/protocols`` (a whitelist),
  ``access_control/{enabled, default_permission, rules, subjects, policies}`` with rule fields ``id``,
  ``messages``, ``flows``, ``permission``, ``key_exprs`` and subject fields ``id``, ``usernames``,
  ``link_protocols``.
- The dictionary file accepts ``user:password`` lines and blank lines; a ``#`` comment line makes the
  router fail to start ("invalid format").
- A client that is not allowed to receive the subscriber declarations (egress ``declare_subscriber``) never
  sees a matching subscriber, and a 1.x client then sends nothing at all: publishers need that egress rule.
- A denied ``put`` is dropped by the router without an error to the publisher (``put`` returns None,
  ``matching_status`` stays True); it shows only at TRACE level in the router's log
  (``RUST_LOG=zenoh::net::routing::interceptor::access_control=trace``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import ipaddress
import json
import os
import re
import secrets
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterable

import zenoh

from common.protocol import ROOT
from common.transport import DEFAULT_CONNECT_TIMEOUT, LOOPBACK, make_config

DEFAULT_PORT = 7447
SECURITY_FILE = "security.json"
CREDENTIALS_FILE = "credentials.txt"
CA_CERT, CA_KEY = "ca.pem", "ca.key"
ROUTER_CERT, ROUTER_KEY = "router.pem", "router.key"

#: Usernames become zenoh dictionary entries (``user:password``, so no ``:``) and, for teachers, the
#: ``teacher_id`` chunk of the feedback key (common.protocol's NAME_PATTERN without ``:``).
USERNAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
_USERNAME_RE = re.compile(USERNAME_PATTERN[:-1] + r"\Z")

#: The single-identity roles and, for each role, the key kinds it may publish (``hitl/<run>/<kind>``; a
#: trailing ``/*`` covers every name of a named kind). Teachers: their own ``feedback/<username>`` only.
SERVICE_ROLES = ("learner", "actor", "recorder", "perception")
ROLES = SERVICE_ROLES + ("teacher",)
PUBLISH: dict[str, tuple[str, ...]] = {
    "learner": ("weights", "episode", "ingest"),
    "actor": ("step",),
    "recorder": (),
    "perception": ("camera/*", "perception/*"),
    "teacher": (),  # plus feedback/<own username>, added per teacher
}
#: What every authenticated identity may publish besides its role's kinds: liveness and events for humans.
PUBLISH_ALL: tuple[str, ...] = ("status/*", "log/*")
#: Liveliness tokens (services.common.runtime): `alive/<service>` and `alive/<service>/<incarnation>`, each
#: identity only under its own service name (a teacher's is `teacher.<username>`).
ALIVE = "alive"


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

    def for_client(self, username: str, credentials_file: str = CREDENTIALS_FILE,
                   ca_cert: str = CA_CERT) -> "SecurityConfig":
        """The copy a client machine gets: no router files, its own credentials file."""
        self.role_of(username)
        return dataclasses.replace(self, router_cert=None, router_key=None, ca_cert=ca_cert,
                                   credentials_file=credentials_file)


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
    return _write_private(Path(path), "".join(f"{u}:{p}\n" for u, p in creds.items()).encode())


def tls_endpoint(port: int, host: str = LOOPBACK) -> str:
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"  # IPv6 literal
    return f"tls/{host}:{int(port)}"


# -- access control --------------------------------------------------------------------------------------------

def _keys(security: SecurityConfig, kinds: Iterable[str]) -> list[str]:
    return [f"{ROOT}/{security.run}/{k}" for k in kinds]


def access_control(security: SecurityConfig) -> dict[str, Any]:
    """The router's ``access_control`` section: default deny; rules keyed by username.

    - ``read`` (every identity): ``declare_subscriber`` both ways (ingress: a client may subscribe;
      egress: a publisher learns that a subscriber exists, without which a zenoh 1.x client sends
      nothing) and egress ``put`` (the router forwards data to it) on ``hitl/<run>/**``.
    - ``publish-<user>``: ingress ``put`` on the keys its role may publish (:data:`PUBLISH`, plus
      ``feedback/<user>`` for a teacher, plus :data:`PUBLISH_ALL`).
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
        {"id": "read-subscribe", "messages": ["declare_subscriber"], "flows": ["ingress", "egress"],
         "permission": "allow", "key_exprs": [read_scope]},
        {"id": "read-receive", "messages": ["put"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [read_scope]},
        # Who is alive: anyone may watch the tokens (with history: a liveliness query and its replies).
        {"id": "alive-watch", "messages": ["declare_liveliness_subscriber", "liveliness_query", "liveliness_token",
                                           "reply"],
         "flows": ["egress"], "permission": "allow", "key_exprs": [alive_scope]},
        {"id": "alive-ask", "messages": ["declare_liveliness_subscriber", "liveliness_query"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [alive_scope]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "everyone", "usernames": users, "link_protocols": ["tls"]}]
    policies: list[dict[str, Any]] = [{"id": "everyone-reads",
                                       "rules": ["read-subscribe", "read-receive", "alive-watch", "alive-ask"],
                                       "subjects": ["everyone"]}]
    for user in users:
        role = security.role_of(user)
        kinds = list(PUBLISH[role]) + ([f"feedback/{user}"] if role == "teacher" else []) + list(PUBLISH_ALL)
        service = f"teacher.{user}" if role == "teacher" else role
        rules.append({"id": f"publish-{user}", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
                      "key_exprs": _keys(security, kinds)})
        rules.append({"id": f"alive-{user}", "messages": ["liveliness_token"], "flows": ["ingress"],
                      "permission": "allow",
                      "key_exprs": _keys(security, [f"{ALIVE}/{service}", f"{ALIVE}/{service}/*"])})
        subjects.append({"id": f"user-{user}", "usernames": [user], "link_protocols": ["tls"]})
        policies.append({"id": f"{user}-publishes", "rules": [f"publish-{user}", f"alive-{user}"],
                         "subjects": [f"user-{user}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def publish_keys(security: SecurityConfig, username: str) -> list[str]:
    """The key expressions ``username`` may put on (as the router's rules say)."""
    for rule in access_control(security)["rules"]:
        if rule["id"] == f"publish-{username}":
            return list(rule["key_exprs"])
    raise SecurityError(f"unknown user {username!r}")


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


def router_config_for(security: SecurityConfig, port: int | None = None, *, host: str | None = None,
                      timestamping: bool = True) -> zenoh.Config:
    """A secured router (a Python session in router mode) listening on ``tls/<host>:<port>`` only.

    ``host`` defaults to ``security.router_host`` (127.0.0.1 unless configured); use ``"0.0.0.0"`` or the
    machine's address to accept other machines. ``port`` defaults to ``security.port``."""
    endpoint = tls_endpoint(security.port if port is None else port, security.router_host if host is None else host)
    return _apply(make_config("router", listen=[endpoint], timestamping=timestamping), router_settings(security))


def client_config_for(security: SecurityConfig, role: str, endpoint: int | str | None = None, *,
                      teacher: str | None = None, connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
                      timestamping: bool = True) -> zenoh.Config:
    """A secured client of the router for the service ``role`` (learner, actor, recorder, perception, or
    teacher with ``teacher=<username>``). ``endpoint``: None (the configured router), a port on the
    configured router host, or a ``tls/host:port`` endpoint; a ``tcp/`` endpoint is refused."""
    username = security.username(role, teacher)
    config = make_config("client", connect=[security.endpoint(endpoint)], connect_timeout=connect_timeout,
                         timestamping=timestamping)
    return _apply(config, client_settings(security, username))


def router_config_dict(security: SecurityConfig, port: int | None = None, *, host: str | None = None) -> dict:
    """The router config as a nested dict (JSON): what ``zenohd -c FILE`` would take."""
    out: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [tls_endpoint(security.port if port is None else port,
                                              security.router_host if host is None else host)]},
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


# -- certificates ----------------------------------------------------------------------------------------------

def _write_private(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)
    return path


def generate_certificates(out_dir: str | os.PathLike, hosts: Iterable[str] = (), *, days: int = 365,
                          common_name: str = "hitl-router") -> dict[str, Path]:
    """A throwaway CA and a router certificate it signs, for tests and demos (EC P-256, PEM).

    The router certificate's SubjectAltNames are ``localhost``, ``127.0.0.1`` and ``hosts`` (IP addresses or
    DNS names of the router machine, as the clients will dial it). Writes ``ca.pem``, ``ca.key``,
    ``router.pem``, ``router.key`` (keys mode 0600) into ``out_dir``; returns their paths."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc) - datetime.timedelta(minutes=5)
    until = now + datetime.timedelta(days=days)

    def key_pem(key: Any) -> bytes:
        return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                 serialization.NoEncryption())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{common_name} CA {secrets.token_hex(4)}")])
    ca_cert = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
               .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now).not_valid_after(until)
               .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False,
                                            key_encipherment=False, data_encipherment=False, key_agreement=False,
                                            key_cert_sign=True, crl_sign=True, encipher_only=False,
                                            decipher_only=False), critical=True)
               .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
               .sign(ca_key, hashes.SHA256()))

    sans: list[x509.GeneralName] = []
    for h in dict.fromkeys(["localhost", LOOPBACK, *hosts]):
        h = h.strip("[]")
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now).not_valid_after(until)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))

    paths = {"ca_cert": out / CA_CERT, "ca_key": out / CA_KEY, "router_cert": out / ROUTER_CERT,
             "router_key": out / ROUTER_KEY}
    paths["ca_cert"].write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    _write_private(paths["ca_key"], key_pem(ca_key))
    paths["router_cert"].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    _write_private(paths["router_key"], key_pem(key))
    return paths


def new_password() -> str:
    """A random password (32 URL-safe characters, never ``:``)."""
    return secrets.token_urlsafe(24)


def init(out_dir: str | os.PathLike, teachers: Iterable[str], *, hosts: Iterable[str] = (),
         router_host: str = LOOPBACK, port: int = DEFAULT_PORT, run: str = "*", learner: str = "learner",
         actor: str = "actor", recorder: str = "recorder", perception: str | None = "perception",
         days: int = 365) -> SecurityConfig:
    """Write everything a secured deployment needs into ``out_dir`` (see the module docstring) and return
    the router machine's :class:`SecurityConfig`. ``router_host`` (the address clients dial) is added to
    the certificate's names."""
    out = Path(out_dir)
    if (out / SECURITY_FILE).exists():
        raise SecurityError(f"{out / SECURITY_FILE} exists: choose an empty folder")
    security = SecurityConfig(ca_cert=CA_CERT, credentials_file=CREDENTIALS_FILE, router_cert=ROUTER_CERT,
                              router_key=ROUTER_KEY, learner=learner, actor=actor, recorder=recorder,
                              perception=perception, teachers=tuple(teachers), run=run, router_host=router_host,
                              port=port, base_dir=str(out.resolve()))
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    generate_certificates(out, [*hosts, router_host], days=days)
    creds = {user: new_password() for user in security.usernames()}
    write_credentials(out / CREDENTIALS_FILE, creds)
    save_security(security, out / SECURITY_FILE)
    for user, password in creds.items():
        client_dir = out / "clients" / user
        client_dir.mkdir(parents=True, exist_ok=True)
        os.chmod(client_dir, 0o700)
        shutil.copyfile(out / CA_CERT, client_dir / CA_CERT)
        write_credentials(client_dir / CREDENTIALS_FILE, {user: password})
        save_security(security.for_client(user), client_dir / SECURITY_FILE)
    return security


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
