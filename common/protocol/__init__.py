"""The wire protocol of the live system: message types, their JSON Schemas, key expressions.

Each message type is defined once (a frozen dataclass whose fields carry their validation spec); its
JSON Schema (draft 2020-12), its validating decoder and its section of ``docs/protocol.md`` all derive
from that definition. ``python -m services protocol --markdown`` prints the documentation.

Use::

    data = step.encode()                     # validates, returns bytes
    msg = Step.decode(data)                  # validates, raises ProtocolError(reason, detail)
    msg = decode(key, data)                  # by key expression, for subscribers to wildcards
    w = Weights.decode(data, expected={"q.0.weight": (100, 8), ...})

No zenoh or mcap import here: the pure core may use these types too.
"""

from ._base import PROTOCOL_VERSION, Message
from ._console import CONTROL_COMMANDS, MAX_RATE, Control, Credit, CreditedStep, DelayEstimate, Shown
from ._keys import (
    kind_of,
    KEYS,
    MESSAGE_TYPES,
    ROOT,
    KeySpec,
    ParsedKey,
    camera_key,
    carried,
    config_key,
    decode,
    episode_key,
    control_key,
    credit_key,
    feedback_key,
    feedback_wildcard,
    shown_key,
    ingest_key,
    log_key,
    message_type,
    parse_key,
    perception_key,
    reaction_key,
    run_prefix,
    status_key,
    step_key,
    validate_name,
    weights_key,
)
from ._media import Box, CompressedImage, ExpressionPrediction, LOG_LEVELS, Log, Time
from ._fields import NAME_PATTERN, TOKEN_PATTERN
from ._messages import (
    SERVICE_STATES,
    EpisodeSummary,
    Feedback,
    Ingest,
    IngestEntry,
    MAX_INGEST_CREDITS,
    MAX_SHOWN,
    ObserverReaction,
    RunConfig,
    ServiceStatus,
    ShownStep,
    Step,
)
from ._roles import (
    ALIVE,
    NAMED_ROLES,
    OBSERVER_PREFIX,
    OWN_KINDS,
    PUBLISHES,
    ROLES,
    SERVICE_ROLES,
    TEACHER_PREFIX,
    alive_key,
    incarnation_alive_key,
    may_publish,
    observer_service_name,
    publish_patterns,
    sender_of,
    split_identity,
    teacher_id_of,
    teacher_service_name,
)
from ._spec import REASONS, ProtocolError
from ._foxglove import FoxgloveProto, SceneUpdate
from ._info import InfoError, step_info
from ._observe import Request, TensorSummary, WeightsSnapshot
from ._topics import key_from_topic, log_topic
from ._weights import Weights, check_spec

__all__ = [
    "PROTOCOL_VERSION",
    "Message",
    "ProtocolError",
    "REASONS",
    "Step",
    "Feedback",
    "Weights",
    "Ingest",
    "IngestEntry",
    "EpisodeSummary",
    "ServiceStatus",
    "CompressedImage",
    "ExpressionPrediction",
    "Log",
    "LOG_LEVELS",
    "log_key",
    "RunConfig",
    "Time",
    "Box",
    "SERVICE_STATES",
    "NAME_PATTERN",
    "TOKEN_PATTERN",
    "check_spec",
    "KEYS",
    "KeySpec",
    "ParsedKey",
    "MESSAGE_TYPES",
    "ROOT",
    "parse_key",
    "message_type",
    "decode",
    "carried",
    "validate_name",
    "run_prefix",
    "step_key",
    "feedback_key",
    "feedback_wildcard",
    "weights_key",
    "episode_key",
    "ingest_key",
    "status_key",
    "camera_key",
    "perception_key",
    "config_key",
    "ObserverReaction",
    "reaction_key",
    "Shown",
    "ShownStep",
    "MAX_SHOWN",
    "MAX_INGEST_CREDITS",
    "Control",
    "CONTROL_COMMANDS",
    "MAX_RATE",
    "Credit",
    "CreditedStep",
    "DelayEstimate",
    "InfoError",
    "step_info",
    "shown_key",
    "control_key",
    "credit_key",
    "log_topic",
    "key_from_topic",
    "FoxgloveProto",
    "SceneUpdate",
    "Request",
    "TensorSummary",
    "WeightsSnapshot",
    "ALIVE",
    "NAMED_ROLES",
    "OBSERVER_PREFIX",
    "OWN_KINDS",
    "PUBLISHES",
    "ROLES",
    "SERVICE_ROLES",
    "TEACHER_PREFIX",
    "alive_key",
    "incarnation_alive_key",
    "may_publish",
    "observer_service_name",
    "publish_patterns",
    "kind_of",
    "sender_of",
    "split_identity",
    "teacher_id_of",
    "teacher_service_name",
]
