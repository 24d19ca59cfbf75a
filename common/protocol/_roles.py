"""Who is who on the wire: service names, liveliness keys, and which identity may publish on which key.

An identity is a service name: `actor`, `learner`, `recorder`, `launcher`, `teacher.<id>` (a teacher, whose
feedback key is `feedback/<id>`), `observer.<id>` (the face-video observer showing reactions to camera `<id>`),
`perception` (a perception service that is not a teacher). Its role is the part before the first `.`.

:data:`PUBLISHES` is the one table of who may publish what. The authentication gate (`common.wire.auth`, checked
by every receiver) and the secured router's access rules (`common.security`) are both built from it.
"""

from __future__ import annotations

import functools

from ._keys import ROOT, parse_key, validate_name
from ._spec import ProtocolError

TEACHER_PREFIX = "teacher."
OBSERVER_PREFIX = "observer."
ALIVE = "alive"  # liveliness tokens: hitl/<run>/alive/<service>[/<incarnation>]

#: Single-instance services (their identity is the role name).
SERVICE_ROLES = ("actor", "learner", "recorder", "launcher", "perception", "foxglove")
#: Roles whose identity carries a name: `teacher.<id>`, `observer.<id>`.
NAMED_ROLES = ("teacher", "observer")
ROLES = SERVICE_ROLES + NAMED_ROLES

#: Key kinds (`hitl/<run>/<kind>[/<name>]`) each role may publish. `{id}` is the identity's own name
#: (`alice` for `teacher.alice`) or that name followed by `-<anything>` (the people a console teaches for:
#: `web-alice` for `teacher.web`); `*` any name. Every identity may also publish its own status and log
#: (:data:`OWN_KINDS`), under its name or its name followed by `-<anything>`. `config` is written by the
#: recorder into its log, never published.
PUBLISHES: dict[str, tuple[str, ...]] = {
    "actor": ("step", "camera/env"),  # camera/env: the env's own picture for the console (services/actor/render.py)
    "learner": ("weights", "snapshot", "episode", "ingest", "credit/*"),
    "recorder": (),
    "launcher": ("request",),
    "perception": ("camera/*", "perception/*"),
    "foxglove": (),
    # a teacher is a simulated observer, a web console (its screen's steps, the run controls) or the
    # perception service reading a face for it
    "teacher": ("feedback/{id}", "shown/{id}", "control", "camera/*", "perception/*", "request"),
    "observer": ("camera/{id}", "reaction/{id}"),
}
OWN_KINDS = ("status", "log")


def teacher_service_name(teacher_id: str) -> str:
    """The identity (service name, status key, liveliness token) of teacher `teacher_id`."""
    validate_name(teacher_id, "teacher_id")
    return f"{TEACHER_PREFIX}{teacher_id}"


def observer_service_name(teacher_id: str) -> str:
    validate_name(teacher_id, "teacher_id")
    return f"{OBSERVER_PREFIX}{teacher_id}"


def teacher_id_of(service: str) -> str | None:
    """`alice` for `teacher.alice`; None for any other service."""
    return service[len(TEACHER_PREFIX) :] if service.startswith(TEACHER_PREFIX) else None


def split_identity(identity: str) -> tuple[str, str | None]:
    """`teacher.alice` -> (`teacher`, `alice`); `actor` -> (`actor`, None). Raises ProtocolError if unknown."""
    validate_name(identity, "identity")
    role, _, name = identity.partition(".")
    if role in NAMED_ROLES and name:
        return role, name
    if role in SERVICE_ROLES and not name:
        return role, None
    raise ProtocolError(
        "bad_value", f"identity {identity[:64]!r}: one of {SERVICE_ROLES} or teacher.<id> / observer.<id>"
    )


def publish_patterns(identity: str) -> tuple[str, ...]:
    """The key tails `identity` may publish: `kind`, `kind/*` (any name), `kind/NAME+` (NAME or NAME-...)."""
    role, name = split_identity(identity)
    own = tuple(f"{k}/{identity}+" for k in OWN_KINDS)
    return tuple(p.replace("{id}", f"{name}+") for p in PUBLISHES[role]) + own


@functools.lru_cache(maxsize=4096)  # checked for every message received: a bounded cache
def may_publish(identity: str, key: str) -> bool:
    """True if `identity` may publish on the concrete key `key` (the run is not checked here)."""
    try:
        parsed = parse_key(key)
        patterns = publish_patterns(identity)
    except ProtocolError:
        return False
    for p in patterns:
        kind, _, name = p.partition("/")
        if kind != parsed.spec.kind:
            continue
        if not name and parsed.name is None:
            return True
        if not name or parsed.name is None:
            continue
        if name == "*" or name == parsed.name:
            return True
        if name.endswith("+") and (parsed.name == name[:-1] or parsed.name.startswith(name[:-1] + "-")):
            return True
    return False


#: Who publishes each kind in a run started by the launcher (for re-publishing a recorded run: `replay play`).
_SENDER = {
    "step": "actor",
    "weights": "learner",
    "episode": "learner",
    "ingest": "learner",
    "credit": "learner",
    "feedback": TEACHER_PREFIX,
    "shown": TEACHER_PREFIX,
    "perception": TEACHER_PREFIX,
    "reaction": OBSERVER_PREFIX,
    "camera": OBSERVER_PREFIX,
}


def sender_of(key: str) -> str | None:
    """The identity that publishes `key` in a launcher's run (`status/<s>` and `log/<s>`: `<s>`); None if nobody
    in particular (`config`, `control`) or not a key of ours."""
    try:
        parsed = parse_key(key)
    except ProtocolError:
        return None
    kind = parsed.spec.kind
    if kind in OWN_KINDS:
        return parsed.name
    who = _SENDER.get(kind)
    if who is None or not who.endswith("."):
        return who
    return f"{who}{parsed.name}"


def alive_key(run: str, service: str = "*") -> str:
    """Liveliness token of a ready service (`*`: every service of the run)."""
    validate_name(run, "run")
    return f"{ROOT}/{run}/{ALIVE}/{service}"


def incarnation_alive_key(run: str, service: str, incarnation: str = "*") -> str:
    """Liveliness token of one incarnation of a service (`*`: every incarnation)."""
    return f"{alive_key(run, service)}/{incarnation}"
