"""A measurement: hand-written msgspec Structs for Step, Feedback and Credit against the protocol's own codec.

Run `python -m common.protocol.msgspec_bench`: round trips both ways, hostile input to both decoders, lines of each
schema, and timings, where "full" is the hand-written check alone and "engine" is `encode`/`decode` as they are
(msgspec generated from the specs, `_fast.py`, since 29 November). Findings: docs/notes/2026-11-28-msgspec.md.
Not checkable by a Struct: repeated keys (msgspec keeps the last: msgspec issue 648), the size limit, and finite
floats on *encode* (msgspec writes NaN and +-Infinity as `null`); cross-field rules go in `__post_init__`.
"""

from __future__ import annotations

import io
import json
import sys
import timeit
import tokenize
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import msgspec
from msgspec import Meta

from ._base import Message, parse_json
from .log_bench import full_encode, report
from ._console import CREDIT_STATUSES, MAX_DELAY_BINS, Credit, CreditedStep, DelayEstimate
from ._fields import NAME_PATTERN, TOKEN_PATTERN
from ._messages import MAX_INFO_ITEMS, MAX_INFO_KEY, MAX_OBS, MAX_SHOWN, Feedback, ShownStep, Step
from ._spec import SAFE_INT, ProtocolError

# --- msgspec schema: begin ------------------------------------------------------------------------------------
# msgspec matches a pattern with re.search, where `$` also matches before a final newline: end it as BASE64 does.
END = r"(?![\s\S])"
Name = Annotated[str, Meta(min_length=1, max_length=64, pattern=NAME_PATTERN[:-1] + END)]
Token = Annotated[str, Meta(min_length=1, max_length=128, pattern=TOKEN_PATTERN[:-1] + END)]
Count = Annotated[int, Meta(ge=0, le=SAFE_INT)]
Seconds = Annotated[float, Meta(ge=0.0)]  # finite: the JSON decoder rejects NaN, Infinity and 1e999
Unit = Annotated[float, Meta(ge=0.0, le=1.0)]
Delay = Annotated[float, Meta(ge=0.0, le=60.0)]
Sign = Literal[-1, 1]
Obs = Annotated[list[float], Meta(min_length=1, max_length=MAX_OBS)]
InfoKey = Annotated[str, Meta(min_length=1, max_length=MAX_INFO_KEY)]
Status = Literal["credited", "stale", "too_old", "ignored", "after_end", "actor_restarted", "duplicate"]
assert get_args(Status) == CREDIT_STATUSES


class Wire(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Base of the wire Structs: immutable, no field the type does not define."""


class StepS(Wire, frozen=True):
    run: Name
    incarnation: Token
    seq: Count
    t_action: Seconds
    episode: Count
    t_in_episode: Count
    obs: Obs
    action: Annotated[int, Meta(ge=0, le=1023)]
    reward: float
    next_obs: Obs
    terminated: bool
    truncated: bool
    weights_version: Count
    info: Annotated[dict[InfoKey, float], Meta(max_length=MAX_INFO_ITEMS)]
    weights_revision: Count | None = None

    def __post_init__(self) -> None:
        if len(self.next_obs) != len(self.obs):
            raise ProtocolError("bad_shape", f"next_obs has {len(self.next_obs)} items, obs has {len(self.obs)}")


class ShownStepS(Wire, frozen=True):
    seq: Count
    t: Seconds


class FeedbackS(Wire, frozen=True):
    run: Name
    teacher_id: Name
    seq: Count
    t_reaction: Seconds
    value: Sign
    source: Name
    ref_seq: Count | None = None
    intended: Sign | None = None
    t_page: Seconds | None = None
    actor: Token | None = None
    shown: Annotated[list[ShownStepS], Meta(max_length=MAX_SHOWN)] | None = None

    def __post_init__(self) -> None:
        if self.shown is not None:
            if self.actor is None:
                raise ProtocolError("bad_value", "shown needs actor")
            for a, b in zip(self.shown, self.shown[1:]):
                if not (b.seq > a.seq and b.t >= a.t):
                    raise ProtocolError("bad_value", "shown must be ascending in seq and time")


class CreditedStepS(Wire, frozen=True):
    seq: Count
    weight: Unit


class DelayEstimateS(Wire, frozen=True):
    median_s: Delay
    p10_s: Delay
    p90_s: Delay
    feedbacks: Count
    bin_s: Annotated[float, Meta(ge=0.001, le=10.0)]
    probs: Annotated[list[Unit], Meta(max_length=MAX_DELAY_BINS)]
    returning: bool  # (required on the wire, as in today's Obj; the dataclass's default is for Python only)


class CreditS(Wire, frozen=True):
    run: Name
    teacher_id: Name
    seq: Count
    value: Sign
    status: Status
    t_reaction: Seconds
    t_credited: Seconds
    actor: Token | None  # nullable but required
    steps: Annotated[list[CreditedStepS], Meta(max_length=256)]
    lost_mass: Unit
    delay: DelayEstimateS | None = None
    revision: Count | None = None


class EpisodeTail(Wire, frozen=True):  # a wire name that is a Python keyword (EpisodeSummary's `return`)
    return_: float = msgspec.field(name="return")


# --- msgspec schema: end --------------------------------------------------------------------------------------

PAIRS: dict[type[Message], type[Wire]] = {Step: StepS, Feedback: FeedbackS, Credit: CreditS}
ENCODER = msgspec.json.Encoder()
DECODERS = {cls: msgspec.json.Decoder(s) for cls, s in PAIRS.items()}


def ms_decode(cls: type[Message], data: bytes) -> Wire:
    """What an adopted decoder would be: today's size limit first, then msgspec."""
    if len(data) > cls.MAX_BYTES:
        raise ProtocolError("oversized", f"{len(data)} bytes > limit {cls.MAX_BYTES}")
    return DECODERS[cls].decode(data)


def reason_of(error: Exception) -> str:
    """A msgspec error as one of today's ProtocolError reasons (for the drop counters), read off its message."""
    if isinstance(error, ProtocolError):
        return error.reason
    if isinstance(error, UnicodeDecodeError):  # (msgspec raises it, not a DecodeError, for bytes not UTF-8)
        return "malformed"
    if isinstance(error, msgspec.DecodeError) and not isinstance(error, msgspec.ValidationError):
        return "malformed"
    text = str(error)
    for prefix, reason in (("bad_shape:", "bad_shape"), ("bad_value:", "bad_value")):
        if text.startswith(prefix):
            return reason
    if "missing required field" in text:
        return "missing_field"
    if "unknown field" in text:
        return "extra_field"
    if "Number out of range" in text:
        return "non_finite"
    if text.startswith("Expected `") and "`, got `" in text:
        return "wrong_type"
    return "bad_value"  # ranges, lengths, patterns, enum values


# --- samples ----------------------------------------------------------------------------------------------------
T0 = 1795853328.123456  # a wall-clock time in late 2026


def step_fields() -> dict[str, Any]:
    """A maze Step (the `mdp` observation: row and column scaled to [0, 1]) with the maze's `info`."""
    names = "target_distance_before target_distance_after path_distance_before path_distance_after subgoal_reached"
    info = dict(zip([*names.split(), "reward", "row", "col"], [7.0, 6.0, 9.0, 8.0, 0.0, -0.01, 3.0, 4.0]))
    return dict(
        run="maze-demo",
        incarnation="actor-7f3a9c2e51d04b6a",
        seq=1234,
        t_action=T0,
        episode=12,
        t_in_episode=37,
        obs=[0.4285714328289032, 0.5714285969734192],
        action=2,
        reward=-0.01,
        next_obs=[0.4285714328289032, 0.7142857313156128],
        terminated=False,
        truncated=False,
        weights_version=88,
        info=info,
        weights_revision=412,
    )


def feedback_fields(shown_type: type) -> dict[str, Any]:
    """A person's press on the console: the 20 steps their screen showed before it (16 steps/s)."""
    shown = [shown_type(seq=1200 + i, t=round(T0 - 1.3 + i / 16 + 0.0041 * (i % 3), 6)) for i in range(20)]
    return dict(
        run="maze-demo",
        teacher_id="alice",
        seq=57,
        t_reaction=T0,
        value=1,
        source="console",
        ref_seq=None,
        intended=None,
        t_page=812.4375,
        actor="actor-7f3a9c2e51d04b6a",
        shown=shown,
    )


def credit_fields(step_type: type, delay_type: type) -> dict[str, Any]:
    """The learner's Credit of that press: 30 steps with their weights, and the delay estimate (60 bins)."""
    raw = [((i + 1) * (30 - i)) / 4960.0 for i in range(30)]
    steps = [step_type(seq=1190 + i, weight=round(w, 6)) for i, w in enumerate(raw)]
    probs = [round(max(0.0, 1 - abs(i - 8) / 9) / 9.0, 5) for i in range(60)]
    delay = delay_type(median_s=0.82, p10_s=0.41, p90_s=1.37, feedbacks=57, bin_s=0.1, probs=probs, returning=False)
    return dict(
        run="maze-demo",
        teacher_id="alice",
        seq=57,
        value=1,
        status="credited",
        t_reaction=T0,
        t_credited=T0 + 0.0123,
        actor="actor-7f3a9c2e51d04b6a",
        steps=steps,
        lost_mass=0.03125,
        delay=delay,
        revision=413,
    )


def samples() -> list[tuple[Message, Wire]]:
    return [
        (Step(**step_fields()), StepS(**step_fields())),
        (Feedback(**feedback_fields(ShownStep)), FeedbackS(**feedback_fields(ShownStepS))),
        (Credit(**credit_fields(CreditedStep, DelayEstimate)), CreditS(**credit_fields(CreditedStepS, DelayEstimateS))),
    ]


# --- the checks -------------------------------------------------------------------------------------------------
def round_trips(pairs: list[tuple[Message, Wire]]) -> None:
    print("Round trips (today's bytes -> msgspec, msgspec's bytes -> today's decode):")
    for msg, struct in pairs:
        today, ours = msg.encode(), ENCODER.encode(struct)
        cls = type(msg)
        assert cls.decode(ours) == msg, cls.TYPE_NAME
        assert ms_decode(cls, today) == struct, cls.TYPE_NAME
        assert json.loads(today) == json.loads(ours), cls.TYPE_NAME
        same = "identical bytes" if today == ours else "same JSON value, bytes differ (float spelling: 1e-07 / 1e-7)"
        print(f"  {cls.TYPE_NAME:14} {len(today):5} B  equal both ways; {same}")
    tail = msgspec.json.decode(b'{"return":-1.5}', type=EpisodeTail)
    assert tail.return_ == -1.5 and ENCODER.encode(tail) == b'{"return":-1.5}'


def per_call_us(fn: Any, repeat: int = 7) -> float:
    timer = timeit.Timer(fn)
    number, _ = timer.autorange()  # at least 0.2 s a round
    return min(timer.repeat(repeat=repeat, number=number)) / number * 1e6


def row(msg: Message, struct: Wire) -> list[float]:
    cls, data, obj, decoder = type(msg), msg.encode(), msg.to_json_obj(), DECODERS[type(msg)]
    fns = [
        lambda: full_encode(msg),
        lambda: cls.from_json_obj(parse_json(data, cls.MAX_BYTES)),
        msg.encode,
        lambda: cls.decode(data),
        lambda: decoder.decode(ENCODER.encode(struct)),
        lambda: ms_decode(cls, data),
        lambda: json.dumps(obj, separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode(),
        lambda: json.loads(data),
    ]
    return [per_call_us(f) for f in fns]


def timings(pairs: list[tuple[Message, Wire]]) -> None:
    cols = ["full enc", "full dec", "engine enc", "engine dec", "ms enc+chk", "ms dec", "json.dumps", "json.loads"]
    print("\nMicroseconds per call (best of 7 rounds of >= 0.2 s each); full, engine: see the docstring;")
    print("ms: the hand-written msgspec Structs of this file.\n")
    print("| message | bytes | " + " | ".join(cols) + " | enc full/engine | dec full/engine |")
    print("|---" * (len(cols) + 4) + "|")
    for msg, struct in pairs:
        us = row(msg, struct)
        cells = " | ".join(f"{u:.2f}" for u in us)
        print(f"| {msg.TYPE_NAME} | {len(msg.encode())} | {cells} | {us[0] / us[2]:.1f}x | {us[1] / us[3]:.1f}x |")


def hostile_cases() -> list[tuple[str, type[Message], bytes]]:
    step = step_fields()
    text = json.dumps(step, separators=(",", ":"))

    def edit(**changes: Any) -> bytes:
        return json.dumps({**step, **changes}, separators=(",", ":")).encode()

    shown = json.loads(Feedback(**feedback_fields(ShownStep)).encode())
    return [
        ("NaN literal", Step, text.replace('"reward":-0.01', '"reward":NaN').encode()),
        ("1e999 literal", Step, text.replace('"reward":-0.01', '"reward":1e999').encode()),
        ("duplicate key", Step, text.replace('"seq":1234', '"seq":1234,"seq":99').encode()),
        ("oversized (70 kB of spaces)", Step, text.encode() + b" " * 70_000),
        ("not UTF-8", Step, text.replace("maze-demo", "maze-d\udcffmo").encode("utf-8", "surrogateescape")),
        ("lone surrogate \\ud800", Step, text.replace("maze-demo", "maze\\ud800").encode()),
        ("top level is an array", Step, b"[1,2]"),
        ("wrong type (seq string)", Step, edit(seq="3")),
        ("bool for int (seq true)", Step, edit(seq=True)),
        ("1.0 for int (seq)", Step, edit(seq=1.0)),
        ("int past 2^53 (seq)", Step, edit(seq=2**53)),
        ("out of range (action 1024)", Step, edit(action=1024)),
        ("negative count (seq -1)", Step, edit(seq=-1)),
        ("unknown field", Step, edit(extra=1)),
        ("missing field", Step, json.dumps({k: v for k, v in step.items() if k != "reward"}).encode()),
        ("too-long list (obs 1025)", Step, edit(obs=[0.5] * 1025, next_obs=[0.5] * 1025)),
        ("too many info keys (17)", Step, edit(info={f"k{i}": 1.0 for i in range(17)})),
        ("name ends in newline", Step, edit(run="maze\n")),
        ("cross rule (next_obs 3 vs obs 2)", Step, edit(next_obs=[0.1, 0.2, 0.3])),
        ("shown without actor", Feedback, json.dumps({**shown, "actor": None}).encode()),
        ("shown not ascending", Feedback, json.dumps({**shown, "shown": shown["shown"][::-1]}).encode()),
        ("enum (value 0)", Credit, json.dumps({**json.loads(samples()[2][0].encode()), "value": 0}).encode()),
    ]


def outcome(decode: Any, cls: type[Message], data: bytes) -> str:
    try:
        decode(cls, data)
    except (ProtocolError, msgspec.DecodeError) as e:
        return f"rejects ({reason_of(e)})"
    except ValueError as e:  # not one of the errors a subscriber expects
        return f"rejects ({reason_of(e)}, as {type(e).__name__})"
    return "ACCEPTS"


def hostile() -> None:
    print("\nHostile input (reason: today's ProtocolError; msgspec's error mapped by reason_of):\n")
    print("| case | type | today | msgspec (+ size check) |")
    print("|---|---|---|---|")
    for name, cls, data in hostile_cases():
        today = outcome(lambda c, d: c.decode(d), cls, data)
        ours = outcome(ms_decode, cls, data)
        flag = "" if today == ours else " **differs**"
        print(f"| {name} | {cls.TYPE_NAME} | {today} | {ours}{flag} |")
    nan = Feedback(**{**feedback_fields(ShownStep), "t_page": float("nan")})
    struct = FeedbackS(**{**feedback_fields(ShownStepS), "t_page": float("nan")})
    written = json.loads(ENCODER.encode(struct))["t_page"]
    print(f"\nEncode of Feedback t_page=NaN: today {outcome(lambda c, d: nan.encode(), Feedback, b'')}; ", end="")
    print(f"msgspec encodes it without error as t_page={json.dumps(written)} (a nullable field: the NaN becomes null)")


# --- line counts ------------------------------------------------------------------------------------------------
HERE = Path(__file__).resolve().parent
VALIDATION = ("_base.py", "_containers.py", "_spec.py", "_fields.py")  # (_base.py also holds the engine, ~70 lines)


def code_lines(text: str) -> int:
    """Lines holding code: not blank, not only a comment, not a docstring."""
    lines: set[int] = set()
    previous = tokenize.NEWLINE
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        skip = tok.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT)
        docstring = tok.type == tokenize.STRING and previous in (tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT)
        if not skip and not docstring:
            lines.update(range(tok.start[0], tok.end[0] + 1))
        if tok.type not in (tokenize.COMMENT, tokenize.NL):
            previous = tok.type
    return len(lines)


def line_counts() -> None:
    print("\nLines (all / code):")
    for name in VALIDATION:
        text = (HERE / name).read_text()
        print(f"  {name:16} {len(text.splitlines()):4} / {code_lines(text)}")
    own = Path(__file__).read_text()
    begin, end = own.index("# --- msgspec schema: begin"), own.index("# --- msgspec schema: end")
    section = own[begin:end]
    print(
        f"  msgspec Structs for Step, Feedback, Credit (this file): {len(section.splitlines())} / {code_lines(section)}"
    )


def main() -> None:
    if sys.argv[1:2] in (["-h"], ["--help"]):
        return print(__doc__, "\nWith a log, `... msgspec_bench RUN/session.mcap`: the same on a run's traffic.")
    if len(sys.argv) > 1:  # a run's log: the engine against the full check on its traffic (log_bench.py)
        return report(sys.argv[1])
    print(f"msgspec {msgspec.__version__}")
    pairs = samples()
    round_trips(pairs)
    hostile()
    line_counts()
    timings(pairs)


if __name__ == "__main__":
    main()
