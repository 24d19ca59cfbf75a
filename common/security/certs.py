"""Certificates (a throwaway CA and the router's) and ``init``: everything a secured deployment needs."""

from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
import shutil
from pathlib import Path
from typing import Any
from collections.abc import Iterable

from common.security.config import (
    CA_CERT,
    CA_KEY,
    CREDENTIALS_FILE,
    DEFAULT_PORT,
    ROUTER_CERT,
    ROUTER_KEY,
    SECURITY_FILE,
    SecurityConfig,
    SecurityError,
    save_security,
    write_credentials,
)
from common.security.files import write_private
from common.wire.transport import LOOPBACK

# -- certificates ----------------------------------------------------------------------------------------------


def _subject_alt_names(hosts: Iterable[str]) -> list:
    """The router certificate's names: localhost, 127.0.0.1 and `hosts` (IP addresses or DNS names)."""
    from cryptography import x509

    sans: list[x509.GeneralName] = []
    for h in dict.fromkeys(["localhost", LOOPBACK, *hosts]):
        h = h.strip("[]")
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    return sans


def _ca_key_usage() -> Any:
    """A CA key signs certificates and revocation lists, nothing else."""
    from cryptography import x509

    no = dict.fromkeys(
        ("digital_signature", "content_commitment", "key_encipherment", "data_encipherment", "key_agreement"), False
    )
    return x509.KeyUsage(**no, key_cert_sign=True, crl_sign=True, encipher_only=False, decipher_only=False)


def generate_certificates(
    out_dir: str | os.PathLike, hosts: Iterable[str] = (), *, days: int = 365, common_name: str = "hitl-router"
) -> dict[str, Path]:
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
    now = datetime.datetime.now(datetime.UTC) - datetime.timedelta(minutes=5)
    until = now + datetime.timedelta(days=days)

    def key_pem(key: Any) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{common_name} CA {secrets.token_hex(4)}")])
    ca_cert = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_ca_key_usage(), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )

    sans = _subject_alt_names(hosts)
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
        .issuer_name(ca_name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(sans), critical=False)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )

    paths = {
        "ca_cert": out / CA_CERT,
        "ca_key": out / CA_KEY,
        "router_cert": out / ROUTER_CERT,
        "router_key": out / ROUTER_KEY,
    }
    paths["ca_cert"].write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    write_private(paths["ca_key"], key_pem(ca_key))
    paths["router_cert"].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    write_private(paths["router_key"], key_pem(key))
    return paths


def new_password() -> str:
    """A random password (32 URL-safe characters, never ``:``)."""
    return secrets.token_urlsafe(24)


def init(
    out_dir: str | os.PathLike,
    teachers: Iterable[str],
    *,
    hosts: Iterable[str] = (),
    router_host: str = LOOPBACK,
    port: int = DEFAULT_PORT,
    run: str = "*",
    learner: str = "learner",
    actor: str = "actor",
    recorder: str = "recorder",
    perception: str | None = "perception",
    days: int = 365,
) -> SecurityConfig:
    """Write everything a secured deployment needs into ``out_dir`` (see the module docstring) and return
    the router machine's :class:`SecurityConfig`. ``router_host`` (the address clients dial) is added to
    the certificate's names."""
    out = Path(out_dir)
    if (out / SECURITY_FILE).exists():
        raise SecurityError(f"{out / SECURITY_FILE} exists: choose an empty folder")
    security = SecurityConfig(
        ca_cert=CA_CERT,
        credentials_file=CREDENTIALS_FILE,
        router_cert=ROUTER_CERT,
        router_key=ROUTER_KEY,
        learner=learner,
        actor=actor,
        recorder=recorder,
        perception=perception,
        teachers=tuple(teachers),
        run=run,
        router_host=router_host,
        port=port,
        base_dir=str(out.resolve()),
    )
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
