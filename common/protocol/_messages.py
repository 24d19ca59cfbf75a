"""The JSON message types, each defined once here (its schema, validator and docs derive from it), and `step_info`:
an environment's `info` as a Step carries it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar

from ._base import PROTOCOL_VERSION, AnyJSON, Embedded, List, Map, Message, Nullable, Obj, fld
from ._fields import RUN, TOKEN_PATTERN, Count, Name, Seconds, Token
from ._spec import Bool, Float, Int, ProtocolError, Str

MAX_OBS = 1024  # observation length limit (the paper's largest is Taxi's one-hot of 19)
MAX_INFO_ITEMS = 16  # Step.info entries: the env's numeric extras a teacher rule reads
MAX_INFO_KEY = 64  # characters in one Step.info key


@dataclasses.dataclass(frozen=True)
class Step(Message):
    """One environment step taken by an actor: the transition and when its action was taken.

    Published by the actor on `hitl/<run>/step` for each step, in order. `seq` is contiguous per
    `incarnation`, so a subscriber detects loss (a gap) and a restarted actor (a new incarnation).
    """

    TYPE_NAME: ClassVar[str] = "hitl.Step"
    MAX_BYTES: ClassVar[int] = 64 * 1024
    CROSS_RULES: ClassVar[tuple[str, ...]] = ("`len(next_obs) == len(obs)`, else `bad_shape`",)

    run: str = fld(Name(RUN))
    incarnation: str = fld(Token("The actor process's own id, new at every start."))
    seq: int = fld(Count("Message counter, 0, 1, 2, ... without gaps within one incarnation."))
    t_action: float = fld(
        Seconds("Wall-clock time (s since the Unix epoch; virtual time in-process) when the action was taken.")
    )
    episode: int = fld(Count("Episode index within this incarnation."))
    t_in_episode: int = fld(Count("Step index within the episode (0 for the first action)."))
    obs: list = fld(List(Float(), min_items=1, max_items=MAX_OBS, description="Observation before the action."))
    action: int = fld(Int(0, 1023, description="Action index."))
    reward: float = fld(Float(description="Environment reward for this transition."))
    next_obs: list = fld(List(Float(), min_items=1, max_items=MAX_OBS, description="Observation after the action."))
    terminated: bool = fld(Bool(description="The episode ended in a terminal state."))
    truncated: bool = fld(Bool(description="The episode was cut by the step limit."))
    weights_version: int = fld(Count("Version of the weights the actor acted with (0 before any Weights arrived)."))
    info: dict = fld(
        Map(
            Float(),
            max_items=MAX_INFO_ITEMS,
            key_max_len=MAX_INFO_KEY,
            description=(
                "The environment's `info` for this step, whole (finite numbers only), for the "
                "simulated teacher's rule: "
                "e.g. `target_distance_before` / `target_distance_after`, `reward`, and any key the env adds."
            ),
        )
    )
    weights_revision: int | None = fld(
        Nullable(
            Count(
                "Revision of the weights the actor acted with (Weights' `revision`: moved by every Q "
                "or H update); null "
                "before any revised Weights arrived."
            )
        ),
        optional=True,
    )

    def _cross_check(self) -> None:
        if len(self.next_obs) != len(self.obs):
            raise ProtocolError("bad_shape", f"next_obs has {len(self.next_obs)} items, obs has {len(self.obs)}")


@dataclasses.dataclass(frozen=True)
class ShownStep:
    """One step as a person's screen showed it: the actor's Step.seq and the system time it appeared."""

    seq: int
    t: float


MAX_SHOWN = 64  # steps a feedback may list: 4 s of assumed delay at 16 steps/s

SHOWN_STEP_SPEC = Obj(
    {
        "seq": Int(0, description="Step.seq of the step shown."),
        "t": Float(0.0, description="System time (s) at which it appeared on the screen."),
    },
    cls=ShownStep,
    description="A step on a person's screen.",
)


@dataclasses.dataclass(frozen=True)
class Feedback(Message):
    """One binary feedback signal from a teacher (a simulated oracle or a perceived face).

    Published on `hitl/<run>/feedback/<teacher_id>`. The learner credits it to recent steps by comparing
    `t_reaction` with the steps' `t_action` (never by arrival time). `ref_seq` and `intended` are for
    measurement only and must not be used for learning.
    """

    TYPE_NAME: ClassVar[str] = "hitl.Feedback"
    MAX_BYTES: ClassVar[int] = 8192
    CROSS_RULES: ClassVar[tuple[str, ...]] = (
        "`shown` needs `actor`, and is ascending in `seq` (strictly) and `t`, else `bad_value`",
    )

    run: str = fld(Name(RUN))
    teacher_id: str = fld(Name("Teacher name; also the last chunk of the key."))
    seq: int = fld(Count("Message counter per teacher, without gaps."))
    t_reaction: float = fld(Seconds("Wall-clock time (s) at which the teacher reacted."))
    value: int = fld(Int(enum=(-1, 1), description="The feedback: +1 good, -1 bad."))
    source: str = fld(Name("Where it came from, e.g. `oracle`, `face`."))
    ref_seq: int | None = fld(
        Nullable(Count("Diagnostics: the Step.seq the simulated observer meant; null if unknown.")), optional=True
    )
    intended: int | None = fld(
        Nullable(
            Int(enum=(-1, 1), description=("Diagnostics: the value before a simulated misread; null if unknown."))
        ),
        optional=True,
    )
    t_page: float | None = fld(
        Nullable(
            Float(
                0.0,
                description=(
                    "A person's action on the console page: its time on the page's clock (s); "
                    "`t_reaction` is this time "
                    "mapped to the system clock with the page's estimated offset."
                ),
            )
        ),
        optional=True,
    )
    actor: str | None = fld(Nullable(Token("The actor incarnation whose steps `shown` lists.")), optional=True)
    shown: list | None = fld(
        Nullable(
            List(
                SHOWN_STEP_SPEC,
                max_items=MAX_SHOWN,
                description=(
                    "The steps on the person's screen before `t_reaction`, oldest first, each with the system time it "
                    "appeared; the learner credits the feedback in seconds over these on-screen "
                    "intervals. Null: credit "
                    "by the actor's step times (simulated teachers)."
                ),
            )
        ),
        optional=True,
    )

    def _cross_check(self) -> None:
        if self.shown is not None:
            if self.actor is None:
                raise ProtocolError("bad_value", "shown needs actor")
            for a, b in zip(self.shown, self.shown[1:]):
                if not (b.seq > a.seq and b.t >= a.t):
                    raise ProtocolError("bad_value", "shown must be ascending in seq and time")


@dataclasses.dataclass(frozen=True)
class EpisodeSummary(Message):
    """End-of-episode numbers (published on `hitl/<run>/episode` by the learner, which sees the episode's steps
    and what became of its feedback; `incarnation` is the actor's)."""

    TYPE_NAME: ClassVar[str] = "hitl.EpisodeSummary"
    MAX_BYTES: ClassVar[int] = 4096

    run: str = fld(Name(RUN))
    incarnation: str = fld(Token("The actor's incarnation."))
    episode: int = fld(Count("Episode index."))
    return_: float = fld(Float(description="Sum of environment rewards in the episode."), wire="return")
    steps: int = fld(Count("Number of steps in the episode."))
    feedback_received: int = fld(Count("Feedback messages received during the episode."))
    feedback_credited: int = fld(Count("Feedback messages credited to at least one step of the episode."))
    weights_version: int = fld(Count("Weights version in use at the end of the episode."))
    t_end: float = fld(Seconds("Wall-clock time (s) when the episode ended."))


INGEST_KINDS = ("step", "feedback", "end", "outcome", "idle")


@dataclasses.dataclass(frozen=True)
class IngestEntry:
    """One line of a learner's ingest record (see `Ingest`)."""

    kind: str
    source: str
    seq: int
    status: str
    t: float


INGEST_ENTRY_SPEC = Obj(
    {
        "kind": Str(
            enum=INGEST_KINDS,
            description=(
                "`step` / `feedback`: an input consumed, in consumption order; `end`: the learner "
                "stopped taking inputs; "
                "`outcome`: what became of a feedback (not an input; retrain checks it); `idle`: an "
                "extra Q and D_global "
                "minibatch step the learner took between two steps of a paced run (retrain repeats it)."
            ),
        ),
        "source": Str(
            128,
            pattern=TOKEN_PATTERN,
            min_len=1,
            description=(
                "The input's origin: the actor incarnation (step), the teacher id (feedback, "
                "outcome), the learner (end)."
            ),
        ),
        "seq": Int(0, description="The input's own `seq` (Step.seq, Feedback.seq); 0 for `end`."),
        "status": Str(
            32,
            description=(
                "For `outcome`: credited, stale, too_old (a person's press whose steps all left the history), ignored, "
                "after_end, actor_restarted; for `step`: learned, gap, old, "
                "after_end; "
                "else empty."
            ),
        ),
        "t": Float(0.0, description="Wall-clock time (s) of consumption: diagnostics only, never used by retrain."),
    },
    cls=IngestEntry,
    description="One ingest entry.",
)


MAX_INGEST_CREDITS = 64  # Credits one Ingest message may carry


@dataclasses.dataclass(frozen=True)
class Ingest(Message):
    """A learner's record of the inputs it consumed, in the order it consumed them (published on
    `hitl/<run>/ingest`, in batches, and logged by the recorder).

    Every learning decision of the learner depends only on this ordered input, so feeding a fresh learner the
    recorded Step and Feedback messages in this order reproduces its weights bit for bit (`replay retrain`).
    `seq` is contiguous per learner incarnation; `index` is the position of the first entry in the learner's
    whole record. The first batch (`seq` 0) carries the learner's config. A learner restored from a checkpoint
    continues the record of the learner it replaces: its config names `resumed_from` (`learner`, `position`),
    its `index` starts at that position, and the old learner's entries from that position on are superseded.
    """

    TYPE_NAME: ClassVar[str] = "hitl.Ingest"
    MAX_BYTES: ClassVar[int] = 512 * 1024 + MAX_INGEST_CREDITS * 10240  # (10240: Credit.MAX_BYTES)
    CROSS_RULES: ClassVar[tuple[str, ...]] = ("every credit's `run` is the Ingest's `run`, else `bad_value`",)

    run: str = fld(Name(RUN))
    learner: str = fld(Token("The learner process's incarnation."))
    seq: int = fld(Count("Batch counter, 0, 1, 2, ... without gaps within one learner incarnation."))
    index: int = fld(Count("Position of the first entry in this incarnation's record."))
    entries: list = fld(List(INGEST_ENTRY_SPEC, max_items=2048, description="Entries in consumption order."))
    config: dict | None = fld(
        Nullable(
            AnyJSON(
                object_only=True,
                description=("The learner's config (first batch only): everything retrain needs to rebuild it."),
            )
        ),
        optional=True,
    )
    credits: list | None = fld(
        Nullable(
            List(
                Embedded(lambda: _credit_type()),
                max_items=MAX_INGEST_CREDITS,
                description=(
                    "What became of feedback from the teachers whose Credits ride here rather than "
                    "on their own key (the "
                    "learner's `credits-in-ingest`: a run's own teacher services, one message less per feedback). The "
                    "recorder logs each on `/credit/<teacher_id>` as if it had come alone."
                ),
            )
        ),
        optional=True,
    )

    def _cross_check(self) -> None:
        if any(c.run != self.run for c in self.credits or ()):
            raise ProtocolError("bad_value", "a credit of another run")


def _credit_type() -> type:
    from ._console import Credit  # (the console's module, which imports this one)

    return Credit


#: `stopped`: done with its part of the run (receivers waiting on it may end); `failed`: ended without
#: finishing (an error, or it gave up): receivers keep waiting, the launcher restarts it.
SERVICE_STATES = ("starting", "ready", "stopping", "stopped", "failed")


@dataclasses.dataclass(frozen=True)
class ServiceStatus(Message):
    """Liveness and counters of one service (published on `hitl/<run>/status/<service>`), e.g. once a
    second and at every state change. `counters` carries drop counts by ProtocolError reason."""

    TYPE_NAME: ClassVar[str] = "hitl.ServiceStatus"
    MAX_BYTES: ClassVar[int] = 16 * 1024

    run: str = fld(Name(RUN))
    service: str = fld(Name("Service name; also the last chunk of the key."))
    pid: int = fld(Int(0, 2**32 - 1, description="Operating-system process id."))
    state: str = fld(Str(enum=SERVICE_STATES, description="Life-cycle state."))
    t: float = fld(Seconds("Wall-clock time (s) of this status."))
    counters: dict = fld(
        Map(Count(""), max_items=256, description="Named counters, e.g. `steps_published`, `dropped_malformed`.")
    )
    incarnation: str | None = fld(
        Nullable(
            Token(
                "The process's own id (as Step.incarnation, Weights.incarnation, Ingest.learner): a subscriber accepts "
                "steps or weights from a new incarnation only once its status has announced it."
            )
        ),
        optional=True,
    )


@dataclasses.dataclass(frozen=True)
class RunConfig(Message):
    """The run's configuration: the first message of every log (on `hitl/<run>/config`) and the
    log's MCAP metadata. `config` is the core's config dataclass as a JSON object."""

    TYPE_NAME: ClassVar[str] = "hitl.RunConfig"
    MAX_BYTES: ClassVar[int] = 1024 * 1024

    run: str = fld(Name(RUN))
    t_created: float = fld(Seconds("Wall-clock time (s) when the run was configured."))
    protocol: int = fld(Int(enum=(PROTOCOL_VERSION,), description="Protocol version of every message in the run."))
    config: dict = fld(AnyJSON(object_only=True, description="The run's configuration (free-form JSON object)."))

    @classmethod
    def create(cls, run: str, config: dict[str, Any], t_created: float | None = None) -> RunConfig:
        import time

        return cls(
            run=run, t_created=time.time() if t_created is None else t_created, protocol=PROTOCOL_VERSION, config=config
        )


# -- Step.info from an environment's `info`: the whole mapping, or an error naming the key that cannot be sent --


class InfoError(ValueError):
    """An environment's `info` that a Step cannot carry; the message names the key."""


def _number(key: str, value: Any) -> float:
    if isinstance(value, (str, bytes)) or value is None:
        raise InfoError(
            f"env info key {key!r}: {type(value).__name__} {value!r:.60} is not a number (a Step carries numbers only)"
        )
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InfoError(
            f"env info key {key!r}: {type(value).__name__} {value!r:.60} is not a number (a Step carries numbers only)"
        ) from None
    if not math.isfinite(number):
        raise InfoError(f"env info key {key!r}: {number} is not a finite number (a Step carries finite numbers only)")
    return number


def step_info(info: Mapping[str, Any]) -> dict[str, float]:
    """The environment's `info` as Step.info carries it: every key, each a finite number (a bool is 0/1).

    Raises InfoError naming the first key that cannot be sent (not 1..`MAX_INFO_KEY` printable characters, not
    a finite number) or the keys past `MAX_INFO_ITEMS`: a teacher rule sees what the env said, never a silently
    shortened copy."""
    if not isinstance(info, Mapping):
        raise InfoError(f"env info must be a mapping of names to numbers, got {type(info).__name__}")
    out: dict[str, float] = {}
    for key, value in info.items():
        if not isinstance(key, str) or not 1 <= len(key) <= MAX_INFO_KEY or not key.isprintable():
            raise InfoError(f"env info key {key!r:.80}: a Step carries keys of 1..{MAX_INFO_KEY} printable characters")
        out[key] = _number(key, value)
    if len(out) > MAX_INFO_ITEMS:
        extra = ", ".join(repr(k) for k in list(out)[MAX_INFO_ITEMS:])
        raise InfoError(
            f"env info has {len(out)} keys, a Step carries at most {MAX_INFO_ITEMS}: {extra} cannot be sent"
        )
    return out
