"""Authentication of every message that changes a run (issue 10): an HMAC tag per message, checked first.

The launcher (or `python -m services credentials` for services started by hand) makes a random secret per
run. Each identity (`actor`, `learner`, `teacher.alice`, ... : `common.protocol` roles) signs with its own key
``K_id = HMAC-SHA256(secret, "hitl-auth-v1/<run>/<identity>")``. Every published sample carries, as its Zenoh
attachment, an envelope: who signed it, the signer's process incarnation, a counter, the signing time and a
tag ``HMAC-SHA256(K_id, key expression | envelope header | payload)``. Every receiver checks the envelope
before anything else (before the sample is even queued): an unknown or missing envelope, an identity that may
not publish on that key (`common.protocol.may_publish`), a wrong tag, or a replayed counter drops the sample
and counts it (`dropped_<reason>`, :data:`AUTH_REASONS`).

Credential files (JSON, mode 0600 in a 0700 folder) come in two kinds:

- a **service** credential holds the run secret: it signs as its identity and verifies every identity of the
  run (services hear from everyone, including teachers that join later);
- a **teacher** credential (`make_teacher_credential`, e.g. for the web console) holds only its own key and
  the keys of the services a teacher listens to (actor, learner, launcher, recorder), never the secret: it
  cannot sign as another teacher. On the secured router the access rules also confine it to its own keys.

Replays: per (identity, key) a receiver keeps one counter per incarnation (the latest MAX_INCARNATIONS): a sample
must count up in its own incarnation. Incarnations are not ordered by time, so a copy forged with a stolen teacher
key under a new incarnation and a later time cannot make a receiver drop the real teacher's next press (issue 33);
an old sample replayed late is still refused by its signing time (`stale_signature`). No zenoh import.
"""

from __future__ import annotations

import dataclasses
import hmac
import json
import os
import secrets
import struct
import threading
import time
from pathlib import Path
from typing import Any
from collections.abc import Iterable

from common.protocol import (
    SERVICE_ROLES,
    kind_of,
    may_publish,
    observer_service_name,
    sender_of,
    split_identity,
    teacher_service_name,
)

VERSION = b"H1"
TAG_BYTES = 32
_HEAD = struct.Struct(">QdB")  # counter, signing time, len(incarnation)
DOMAIN = b"hitl-auth-v1"
MAX_INCARNATIONS = 16  # incarnations of one signer on one key whose counters a receiver keeps
#: Identities whose keys a teacher credential carries (to check what a teacher listens to).
TEACHER_VERIFIES = ("actor", "learner", "launcher", "recorder")

AUTH_REASONS: dict[str, str] = {
    "unauthenticated": "no authentication envelope, or one that does not parse",
    "not_permitted": "the signer may not publish on this key (common.protocol.PUBLISHES), or is unknown here",
    "bad_tag": "the tag does not match the payload, key and signer (forged or altered)",
    "replayed": "a counter not newer than one already accepted from the same incarnation of the signer",
    "stale_signature": "signed more than `max_past` s before arrival or `max_future` s after",
}


class AuthError(ValueError):
    """A credential that cannot be used (missing file, wrong run, bad content)."""


def derive_key(secret: bytes, run: str, identity: str) -> bytes:
    return hmac.digest(secret, DOMAIN + f"/{run}/{identity}".encode(), "sha256")


@dataclasses.dataclass(frozen=True)
class Credential:
    """One identity's credential for one run. `secret` (services only) verifies any identity; `verify` maps
    the identities a teacher may check to their keys."""

    identity: str
    run: str
    key: bytes
    secret: bytes | None = None
    verify: dict[str, bytes] = dataclasses.field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "service" if self.secret is not None else "teacher"

    def key_of(self, identity: str) -> bytes | None:
        if identity == self.identity:
            return self.key
        if self.secret is not None:
            return derive_key(self.secret, self.run, identity)
        return self.verify.get(identity)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "identity": self.identity, "run": self.run, "key": self.key.hex()}
        if self.secret is not None:
            out["secret"] = self.secret.hex()
        if self.verify:
            out["verify"] = {k: v.hex() for k, v in sorted(self.verify.items())}
        return out

    @classmethod
    def from_json(cls, obj: Any, where: str = "credential") -> Credential:
        try:
            secret = bytes.fromhex(obj["secret"]) if "secret" in obj else None
            cred = cls(
                identity=str(obj["identity"]),
                run=str(obj["run"]),
                key=bytes.fromhex(obj["key"]),
                secret=secret,
                verify={str(k): bytes.fromhex(v) for k, v in obj.get("verify", {}).items()},
            )
            split_identity(cred.identity)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise AuthError(f"{where}: not a credential ({exc})") from None
        if secret is not None and derive_key(secret, cred.run, cred.identity) != cred.key:
            raise AuthError(f"{where}: key and secret disagree")
        return cred


def _write_private(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.chmod(path.parent, 0o700)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)
    return path


def save_credential(cred: Credential, path: str | os.PathLike) -> Path:
    return _write_private(Path(path), (json.dumps(cred.to_json(), indent=1) + "\n").encode())


def load_credential(path: str | os.PathLike, run: str | None = None, identity: str | None = None) -> Credential:
    """Read a credential file; refuse one readable by others, of another run or of another identity."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
        obj = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise AuthError(f"credentials {p}: {exc}") from None
    if mode & 0o077:
        raise AuthError(f"credentials {p}: readable by others (mode {mode & 0o777:o}); chmod 600 it")
    cred = Credential.from_json(obj, str(p))
    if run is not None and cred.run != run:
        raise AuthError(f"credentials {p} are for run {cred.run!r}, not {run!r}")
    if identity is not None and cred.identity != identity:
        raise AuthError(f"credentials {p} are {cred.identity!r}'s, not {identity!r}'s")
    return cred


SECRET_FILE = "run.secret"


def new_run_secret(folder: str | os.PathLike, run: str) -> bytes:
    """A fresh run secret, saved as `<folder>/run.secret` (0600; refuses to overwrite one)."""
    path = Path(folder) / SECRET_FILE
    if path.exists():
        raise AuthError(f"{path} exists: a run's secret is made once")
    secret = secrets.token_bytes(32)
    _write_private(path, json.dumps({"run": run, "secret": secret.hex()}).encode())
    return secret


def read_run_secret(folder: str | os.PathLike, run: str) -> bytes:
    path = Path(folder) / SECRET_FILE
    try:
        obj = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise AuthError(f"{path}: {exc}") from None
    if obj.get("run") != run:
        raise AuthError(f"{path} is the secret of run {obj.get('run')!r}, not {run!r}")
    return bytes.fromhex(obj["secret"])


def service_credential(secret: bytes, run: str, identity: str) -> Credential:
    return Credential(identity, run, derive_key(secret, run, identity), secret=secret)


def teacher_credential(secret: bytes, run: str, teacher_id: str) -> Credential:
    identity = teacher_service_name(teacher_id)
    # what a teacher hears: the services, and the face-video observer showing its reactions to the camera
    heard = TEACHER_VERIFIES + (observer_service_name(teacher_id),)
    return Credential(
        identity, run, derive_key(secret, run, identity), verify={i: derive_key(secret, run, i) for i in heard}
    )


def make_run_credentials(
    folder: str | os.PathLike, run: str, services: Iterable[str] = SERVICE_ROLES, teachers: Iterable[str] = ()
) -> dict[str, Path]:
    """A new run secret in `folder` and one credential file per identity (`<identity>.json`): service
    credentials for `services` (identities), teacher credentials for `teachers` (teacher ids)."""
    folder = Path(folder)
    secret = new_run_secret(folder, run)
    paths = {i: save_credential(service_credential(secret, run, i), folder / f"{i}.json") for i in services}
    for t in teachers:
        cred = teacher_credential(secret, run, t)
        paths[cred.identity] = save_credential(cred, folder / f"{cred.identity}.json")
    return paths


def make_teacher_credential(
    folder: str | os.PathLike, run: str, teacher_id: str, out: str | os.PathLike | None = None
) -> Path:
    """Give teacher `teacher_id` (a console, a human's teacher process) a credential for the run whose secret
    is in `folder`; written to `out` (default `<folder>/teacher.<id>.json`). Returns its path."""
    cred = teacher_credential(read_run_secret(folder, run), run, teacher_id)
    return save_credential(cred, out or Path(folder) / f"{cred.identity}.json")


# -- signing and checking -----------------------------------------------------------------------------------


def _mac(key: bytes, key_expr: str, header: bytes, payload: bytes) -> bytes:
    return hmac.digest(key, b"".join((key_expr.encode(), b"\0", header, payload)), "sha256")


class Auth:
    """Signs what this process publishes and checks what it receives. Thread-safe: zenoh callbacks of
    several subscriptions may check at once, several threads may sign."""

    def __init__(
        self, cred: Credential, incarnation: str | None = None, *, max_past: float = 600.0, max_future: float = 10.0
    ):
        self.cred = cred
        self.incarnation = (incarnation or secrets.token_hex(8))[:64]
        self.max_past, self.max_future = float(max_past), float(max_future)
        self._counter = 0
        self._lock = threading.Lock()
        self._keys: dict[str, bytes | None] = {}
        self._last: dict[tuple[str, str], dict[str, int]] = {}  # (identity, key) -> {incarnation: counter}
        self.rejected: dict[str, int] = {}  # "<reason>_<key kind>" -> count (a service's `auth_*` counters)
        head = cred.identity.encode()
        self._ident = VERSION + bytes([len(head)]) + head
        self._inc = self.incarnation.encode()

    # -- sender ---------------------------------------------------------------------------------------------
    def sign(self, key_expr: str, payload: bytes) -> bytes:
        """The attachment for `payload` on `key_expr`. Call under the same lock as the put if order matters
        (:meth:`locked`), so counters leave in the order they were drawn."""
        with self._lock:
            self._counter += 1
            n = self._counter
        header = self._ident + _HEAD.pack(n, time.time(), len(self._inc)) + self._inc
        return header + _mac(self.cred.key, key_expr, header, payload)

    # -- receiver -------------------------------------------------------------------------------------------
    def _key_of(self, identity: str) -> bytes | None:
        if identity not in self._keys:
            self._keys[identity] = self.cred.key_of(identity)
        return self._keys[identity]

    def check(
        self,
        key_expr: str,
        payload: bytes,
        attachment: bytes | None,
        t_recv: float | None = None,
        window: dict | None = None,
    ) -> str | None:
        """None if authentic and new, else the reason to drop it (:data:`AUTH_REASONS`), counted. `window`: the
        replay state of one subscription (a sample matching two subscriptions of a process arrives at each once;
        default: this object's own)."""
        reason = self._check(key_expr, payload, attachment, t_recv, self._last if window is None else window)
        if reason is not None:
            kind = kind_of(key_expr)
            name = f"{reason}_{kind if kind.isidentifier() else 'other'}"
            with self._lock:
                self.rejected[name] = self.rejected.get(name, 0) + 1
        return reason

    def _check(
        self, key_expr: str, payload: bytes, attachment: bytes | None, t_recv: float | None, window: dict
    ) -> str | None:
        parsed = _parse(attachment)
        if parsed is None:
            return "unauthenticated"
        identity, n, t, inc, header, tag = parsed
        if not may_publish(identity, key_expr):
            return "not_permitted"
        key = self._key_of(identity)
        if key is None:
            return "not_permitted"
        if not hmac.compare_digest(tag, _mac(key, key_expr, header, payload)):
            return "bad_tag"
        now = time.time() if t_recv is None else t_recv
        if not (now - self.max_past <= t <= now + self.max_future):
            return "stale_signature"
        with self._lock:
            return _count_up(window.setdefault((identity, key_expr), {}), inc, n)


def _count_up(counters: dict[str, int], inc: str, n: int) -> str | None:
    """A sample is new if it counts up in its own incarnation: no other incarnation (a forged one signed later with
    a stolen key) makes a real one's next sample look old. Past MAX_INCARNATIONS the least recently used is
    forgotten (replaying its samples needs that many newer incarnations: a key holder, who can sign anyway)."""
    last = counters.get(inc)
    if last is not None and n <= last:
        return "replayed"
    counters.pop(inc, None)  # (re-inserted last: the dict's order is the order of use)
    counters[inc] = n
    while len(counters) > MAX_INCARNATIONS:
        del counters[next(iter(counters))]
    return None


class SignAsSender:
    """Signs each key as the identity that publishes it in a launcher's run (`common.protocol.sender_of`), with a
    service credential (which holds the run secret): what `replay play` uses to re-publish a recorded run."""

    def __init__(self, cred: Credential):
        if cred.secret is None:
            raise AuthError(
                f"re-publishing a run needs a service credential (with the run secret), not "
                f"{cred.identity!r}'s teacher credential"
            )
        self.cred, self.secret = cred, cred.secret
        self._auths: dict[str, Auth] = {}

    def sign(self, key_expr: str, payload: bytes) -> bytes | None:
        identity = sender_of(key_expr)
        if identity is None:
            return None
        if identity not in self._auths:
            self._auths[identity] = Auth(service_credential(self.secret, self.cred.run, identity))
        return self._auths[identity].sign(key_expr, payload)


def _parse(att: bytes | None) -> tuple[str, int, float, str, bytes, bytes] | None:
    """(identity, counter, t, incarnation, header, tag) or None."""
    if not att or len(att) < 3 + _HEAD.size + TAG_BYTES or att[:2] != VERSION:
        return None
    n_id = att[2]
    at = 3 + n_id
    if len(att) < at + _HEAD.size + TAG_BYTES:
        return None
    try:
        identity = att[3:at].decode("ascii")
        n, t, n_inc = _HEAD.unpack_from(att, at)
        at += _HEAD.size
        inc = att[at : at + n_inc].decode("ascii")
    except (UnicodeDecodeError, struct.error):
        return None
    at += n_inc
    if len(att) != at + TAG_BYTES or t != t:  # NaN time
        return None
    return identity, n, t, inc, att[:at], att[at:]


def signer_identity(attachment: bytes | None) -> str | None:
    """Who claims to have signed (unchecked): for counters and messages only."""
    parsed = _parse(attachment)
    return parsed[0] if parsed else None
