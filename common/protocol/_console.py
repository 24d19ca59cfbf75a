"""Messages of a person in the loop (the console, `services/console`): what their screen showed and when,
the run controls they used, and what the learner made of each feedback (shown back on their page)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from ._base import List, Message, Nullable, Obj, fld
from ._fields import RUN, Count, Name, Seconds, Token
from ._spec import Bool, Float, Int, ProtocolError, Str

CONTROL_COMMANDS = ("pause", "resume", "pace", "end")
MAX_RATE = 50.0  # steps per second a console may ask for
#: `duplicate`: a feedback re-sent after it was consumed (e.g. by a console page after a reconnect): not credited
#: again; the Credit only tells the page that the learner has it.
CREDIT_STATUSES = ("credited", "stale", "too_old", "ignored", "after_end", "actor_restarted", "duplicate")


@dataclasses.dataclass(frozen=True)
class Shown(Message):
    """A step appeared on a person's screen (published by the console on `hitl/<run>/shown/<screen>`).

    `t_shown` is the page's paint time mapped to the system clock with the page's clock offset, estimated as
    NTP does over the console's WebSocket (`offset`, from the exchange with the smallest round trip `rtt`).
    The same times travel in the `shown` list of that person's Feedback, which is what the learner credits by;
    this record is for the log and for measuring display lag (`t_shown - t_action`)."""

    TYPE_NAME: ClassVar[str] = "hitl.Shown"
    MAX_BYTES: ClassVar[int] = 2048
    CROSS_RULES: ClassVar[tuple[str, ...]] = ("`t_shown >= t_action`, else `bad_value`",)

    run: str = fld(Name(RUN))
    screen: str = fld(Name("The person's screen: their teacher id; also the last chunk of the key."))
    actor: str = fld(Token("The actor incarnation of the step."))
    seq: int = fld(Count("Step.seq of the step shown."))
    t_action: float = fld(Seconds("The step's action time (Step.t_action)."))
    t_shown: float = fld(Seconds("System time (s) at which the page painted the step."))
    t_page: float = fld(Seconds("The paint time on the page's clock (s)."))
    offset: float = fld(Float(-1e10, 1e10, description="The page's estimated offset: system time - page time (s)."))
    rtt: float = fld(Float(0.0, 60.0, description="Round trip (s) of the clock exchange the offset came from."))

    def _cross_check(self) -> None:
        if self.t_shown < self.t_action:
            raise ProtocolError("bad_value", f"t_shown {self.t_shown} is before t_action {self.t_action}")


@dataclasses.dataclass(frozen=True)
class Control(Message):
    """A person's run control (published by the console on `hitl/<run>/control`; the actor obeys): `pause`
    stops stepping, `resume` continues, `pace` sets the rate in steps per second, `end` ends the run as if
    its episodes were done."""

    TYPE_NAME: ClassVar[str] = "hitl.Control"
    MAX_BYTES: ClassVar[int] = 1024
    CROSS_RULES: ClassVar[tuple[str, ...]] = ("`rate` is given for `pace` (and only then), else `bad_value`",)

    run: str = fld(Name(RUN))
    source: str = fld(Name("Who asked: the person's teacher id."))
    seq: int = fld(Count("Counter per console process."))
    t: float = fld(Seconds("System time (s) of the request."))
    command: str = fld(Str(enum=CONTROL_COMMANDS, description="pause, resume, pace or end."))
    rate: float | None = fld(Nullable(Float(0.1, MAX_RATE, description="Steps per second (pace only).")), optional=True)

    def _cross_check(self) -> None:
        if (self.command == "pace") != (self.rate is not None):
            raise ProtocolError("bad_value", "rate is for pace only, and pace needs it")


@dataclasses.dataclass(frozen=True)
class CreditedStep:
    seq: int
    weight: float


CREDITED_STEP_SPEC = Obj(
    {
        "seq": Int(0, description="Step.seq (of `actor`)."),
        "weight": Float(0.0, 1.0, description="Credit weight (assumed-delay mass)."),
    },
    cls=CreditedStep,
    description="One step a feedback was credited to.",
)


@dataclasses.dataclass(frozen=True)
class DelayEstimate:
    median_s: float
    p10_s: float
    p90_s: float
    feedbacks: int
    bin_s: float
    probs: list
    returning: bool = False


MAX_DELAY_BINS = 120
DELAY_ESTIMATE_SPEC = Obj(
    {
        "median_s": Float(0.0, 60.0, description="Median delay (s)."),
        "p10_s": Float(0.0, 60.0, description="10th percentile (s)."),
        "p90_s": Float(0.0, 60.0, description="90th percentile (s)."),
        "feedbacks": Int(
            0, description="Feedbacks the estimate has seen (0: the prior, or a returning person's last)."
        ),
        "bin_s": Float(
            0.001, 10.0, description="Width (s) of each density bin; bin i covers [i * bin_s, (i+1) * bin_s)."
        ),
        "probs": List(Float(0.0, 1.0), max_items=MAX_DELAY_BINS, description="Probability of each bin, from 0 s."),
        "returning": Bool(description="The estimate started from this person's profile (their last session's)."),
    },
    cls=DelayEstimate,
    description="The learner's current estimate of this teacher's reaction delay, in seconds.",
)


@dataclasses.dataclass(frozen=True)
class Credit(Message):
    """What the learner did with one feedback (published on `hitl/<run>/credit/<teacher_id>`): the steps it
    credited and their weights, or why none. The console draws it as the feedback's trail."""

    TYPE_NAME: ClassVar[str] = "hitl.Credit"
    MAX_BYTES: ClassVar[int] = 10240

    run: str = fld(Name(RUN))
    teacher_id: str = fld(Name("The feedback's teacher; also the last chunk of the key."))
    seq: int = fld(Count("The feedback's seq."))
    value: int = fld(Int(enum=(-1, 1), description="The feedback's value."))
    status: str = fld(Str(enum=CREDIT_STATUSES, description="What became of it."))
    t_reaction: float = fld(Seconds("The feedback's t_reaction."))
    t_credited: float = fld(Seconds("System time (s) at which the learner updated H with it."))
    actor: str | None = fld(Nullable(Token("The actor incarnation of the steps.")))
    steps: list = fld(
        List(
            CREDITED_STEP_SPEC,
            max_items=256,
            description=("Steps credited, oldest first (the learner lists at most 128: those of largest weight)."),
        )
    )
    lost_mass: float = fld(Float(0.0, 1.0, description="Assumed-delay mass that fell on no step held."))
    delay: DelayEstimate | None = fld(
        Nullable(
            DELAY_ESTIMATE_SPEC,
            description=(
                "The delay the learner now assumes for this teacher (learned, or the fixed one), after this feedback: "
                "the console draws it (absent: not sent)."
            ),
        ),
        optional=True,
    )
    revision: int | None = fld(
        Nullable(
            Count(
                "The weights revision that first includes this feedback's H update: a Step whose "
                "`weights_revision` is at "
                "least this acted on it. Null when crediting it updated nothing at once (reward "
                "shaping, or not credited)."
            )
        ),
        optional=True,
    )
