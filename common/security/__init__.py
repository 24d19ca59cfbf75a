"""Secured Zenoh for multi-machine runs: TLS, user/password authentication and access control (issue 6).

By default every service listens and connects on 127.0.0.1 only (``common.wire.transport``), so nobody else is
let in. To spread the services over several machines, run one secured router and connect every service to
it as a client:

- **TLS** (``tls/HOST:PORT``): the router presents a certificate signed by the run's own CA; every client
  checks it against that CA (``verify_name_on_connect``: the host the client dials must be in the
  certificate's SubjectAltName). Plain ``tcp/`` to the TLS port fails the handshake.
- **User/password** (``transport/auth/usrpwd``): the router holds the dictionary (``user:password`` lines);
  every client proves its own password (an HMAC over a nonce; the password never crosses the wire). No
  credentials, an unknown user or a wrong password: ``zenoh.open`` fails.
- **Access control** on the router (``access_control``, ``default_permission: "deny"``), keyed by username
  and built from the protocol's table (``common.protocol.PUBLISHES``, docs/protocol.md): only the learner may
  put ``hitl/<run>/weights``; teacher ``T`` only ``feedback/T`` (and its console's people ``feedback/T-*``);
  the actor ``step``; each identity only its own ``status/<service>`` and ``log/<service>``. Every
  authenticated identity may subscribe to and receive ``hitl/<run>/**`` (so the recorder records everything).
  A denied put is dropped silently by the router: the publisher gets no error. On top of this, every message
  carries the run's authentication tag (common/wire/auth.py), checked by every receiver.

Modules: config (who is who, security.json), access (the router's rules), zenoh_config, certs (CA, init),
router (the secured router process, the command line).

Use (see docs/security.md)::

    python -m services security init DIR --teachers alice,bob [--hosts 192.168.1.10,router.lan]
    python -m services security router --security DIR/security.json [--host 0.0.0.0] [--port 7447]

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

from common.security.access import access_control, publish_keys, publish_kinds
from common.security.certs import generate_certificates, init, new_password
from common.security.config import (
    CA_CERT,
    CA_KEY,
    CREDENTIALS_FILE,
    DEFAULT_PORT,
    ROLES,
    ROUTER_CERT,
    ROUTER_KEY,
    SECURITY_FILE,
    SERVICE_ROLES,
    USERNAME_PATTERN,
    SecurityConfig,
    SecurityError,
    load_security,
    read_credentials,
    save_security,
    tls_endpoint,
    validate_username,
    write_credentials,
)
from common.security.router import run_secured_router
from common.security.zenoh_config import (
    client_config_for,
    client_settings,
    router_config_dict,
    router_config_for,
    router_settings,
)

__all__ = [
    "access_control",
    "publish_keys",
    "publish_kinds",
    "generate_certificates",
    "init",
    "new_password",
    "CA_CERT",
    "CA_KEY",
    "CREDENTIALS_FILE",
    "DEFAULT_PORT",
    "ROLES",
    "ROUTER_CERT",
    "ROUTER_KEY",
    "SECURITY_FILE",
    "SERVICE_ROLES",
    "USERNAME_PATTERN",
    "SecurityConfig",
    "SecurityError",
    "load_security",
    "read_credentials",
    "save_security",
    "tls_endpoint",
    "validate_username",
    "write_credentials",
    "run_secured_router",
    "client_config_for",
    "client_settings",
    "router_config_dict",
    "router_config_for",
    "router_settings",
]
