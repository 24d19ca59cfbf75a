"""The fast engine: msgspec decoders generated from the same field specs, for messages in their usual form.

The specs stay the one definition (schemas, docs/protocol.md, the Hypothesis strategies and the full check read
them); this module only derives a typed msgspec decoder per message type from them. ``Message.decode`` asks it
first and takes its answer only for a message in the canonical form (``encode``'s own bytes: compact, every field
present, each key once): any other input, valid or not, goes to the full check, which gives today's result and
reason. So what a decoder accepts, and why it rejects, does not depend on this module; only how fast it answers.

Why a canonical form is needed: msgspec keeps the last of repeated keys (the protocol rejects them), reads 1 as a
float and writes NaN as null. Bytes that equal msgspec's encoding of what it decoded have none of those: each key
once, every number in the form it has. An embedded message (an Ingest's Credits) is decoded by its own type's
Structs and finished as that type; a spec msgspec cannot state (``AnyJSON``, ``Bytes64``) becomes ``Any`` there
and is checked by its own ``check`` in Python.

Measured (issue 32, docs/notes/2026-11-28-msgspec.md, "Adopted as an engine"): a Step decodes 2-3x faster, a
Credit about 4x (`python -m common.protocol.msgspec_bench`).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal
from collections.abc import Callable

import msgspec
from msgspec import Meta

from ._base import Embedded, List, Map, Message, Nullable, Obj
from ._spec import Bool, Float, Int, ProtocolError, Spec, Str

__all__ = ["FastDecoder", "fast_decoder", "encode_json"]

_ENCODER = msgspec.json.Encoder()
#: Every JSON value written by ``Message.encode`` (a dict of plain Python values, already checked: finite numbers).
encode_json: Callable[[Any], bytes] = _ENCODER.encode


Convert = Callable[[Any], Any]


class Unstated(Exception):
    """A spec msgspec cannot state, inside another spec: the message type keeps the full check only."""


def _checked(spec: Any) -> Any:
    """The msgspec type that accepts what the spec accepts (a spec it cannot state raises ``Unstated``)."""
    if isinstance(spec, Str):
        if spec.enum is not None:
            return Literal[spec.enum]
        pattern = spec._re.pattern if spec._re is not None else None  # (``\\Z``-ended, as the full check reads it)
        return Annotated[str, Meta(min_length=spec.min_len, max_length=spec.max_len, pattern=pattern)]
    if isinstance(spec, Int):
        if spec.enum is not None:
            return Literal[spec.enum]
        return Annotated[int, Meta(ge=spec.minimum, le=spec.maximum)]
    if isinstance(spec, Float):
        if spec.minimum is None and spec.maximum is None:
            return float
        return Annotated[float, Meta(ge=spec.minimum, le=spec.maximum)]  # (None: no bound)
    if isinstance(spec, Bool):
        return bool
    if isinstance(spec, Nullable):
        return _checked(spec.inner) | None
    if isinstance(spec, List):
        return Annotated[list[_checked(spec.item)], Meta(min_length=spec.min_items, max_length=spec.max_items)]  # type: ignore[misc]
    if isinstance(spec, Map):
        key = Annotated[str, Meta(min_length=1, max_length=spec.key_max_len)]
        return Annotated[dict[key, _checked(spec.value)], Meta(max_length=spec.max_items)]  # type: ignore[misc]
    if isinstance(spec, Obj):
        return _struct("Obj", [(k, k, _checked(v)) for k, v in spec.fields.items()], optional=set())
    if isinstance(spec, Embedded):
        return fast_decoder(spec.cls).checked_type
    raise Unstated(type(spec).__name__)


def _built(spec: Any) -> Any:
    """The msgspec type that builds the full check's value from bytes ``_checked`` accepted: the nested dataclasses
    themselves (msgspec makes them in C), plain types elsewhere."""
    if isinstance(spec, (Str, Int)):
        return str if isinstance(spec, Str) else int
    if isinstance(spec, (Float, Bool)):
        return float if isinstance(spec, Float) else bool
    if isinstance(spec, Nullable):
        return _built(spec.inner) | None
    if isinstance(spec, List):
        return list[_built(spec.item)]  # type: ignore[misc]
    if isinstance(spec, Map):
        return dict[str, _built(spec.value)]  # type: ignore[misc]
    if isinstance(spec, Obj):
        return spec.cls if spec.cls is not None else dict[str, Any]
    if isinstance(spec, Embedded):
        return fast_decoder(spec.cls).built_type
    raise Unstated(type(spec).__name__)


def _finisher(spec: Any) -> Convert | None:
    """How to turn a field's built value into the message's (an embedded message's Struct into the message), or None
    when it already is. An embedded message inside an object or a map is left to the full check."""
    if isinstance(spec, Embedded):
        return fast_decoder(spec.cls).finish
    if isinstance(spec, (Nullable, List)):
        inner = _finisher(spec.inner if isinstance(spec, Nullable) else spec.item)
        if inner is None:
            return None
        if isinstance(spec, List):
            return lambda v: [inner(x) for x in v]
        return lambda v: None if v is None else inner(v)
    if isinstance(spec, (Obj, Map)) and _holds(spec, Embedded):
        raise Unstated("an embedded message in an object or a map")
    return None


def _struct(name: str, fields: list[tuple[str, str, Any]], *, optional: set[str]) -> Any:
    """A frozen Struct with these (attribute, wire name, type) fields, in order, that refuses unknown fields."""
    defs = [
        (attr, typ, msgspec.field(name=wire, default=None) if attr in optional else msgspec.field(name=wire))
        for attr, wire, typ in fields
    ]
    return msgspec.defstruct(name.replace(".", "_"), defs, kw_only=True, frozen=True, forbid_unknown_fields=True)


class FastDecoder:
    """One message type's msgspec decoder. ``decode`` gives the message for canonical valid bytes, else None.

    Two passes in C: the first checks every stated constraint and that the bytes are canonical, the second builds
    the values (nested dataclasses and embedded messages included). A top-level field whose spec msgspec cannot
    state (the run config, an image's base64) is any JSON in both and goes through its spec's own check."""

    def __init__(self, cls: type[Message]):
        self.cls = cls
        fields = cls.wire_fields()
        optional = {wf.attr for wf in fields if wf.optional}
        self.own_checks: list[tuple[str, Any]] = []
        self.finishers: list[tuple[str, Convert]] = []
        checked, built = [], []
        for wf in fields:
            try:
                finish = _finisher(wf.spec)
                checked.append((wf.attr, wf.wire, _checked(wf.spec)))
                built.append((wf.attr, wf.wire, _built(wf.spec)))
                if finish is not None:
                    self.finishers.append((wf.attr, finish))
            except Unstated:
                checked.append((wf.attr, wf.wire, Any))
                built.append((wf.attr, wf.wire, Any))
                self.own_checks.append((wf.attr, wf.spec))
        # msgspec writes a dataclass's attribute names: a type with a renamed field (``return_``) encodes the full way
        self.writes_itself = all(wf.wire == wf.attr for wf in fields)
        name = cls.TYPE_NAME.replace(".", "_")
        self.checked_type = _struct(name, checked, optional=optional)
        self.checker = msgspec.json.Decoder(self.checked_type)
        # (without a nested object the checked values are the built ones: one pass)
        nested = any(_holds(wf.spec, (Obj, Embedded)) for wf in fields)
        self.built_type = _struct(name, built, optional=optional) if nested else self.checked_type
        self.builder = msgspec.json.Decoder(self.built_type) if nested else None

    def decode(self, data: bytes) -> Message | None:
        try:
            checked = self.checker.decode(data)
            if _ENCODER.encode(checked) != data:
                return None  # not the canonical form (spacing, a key twice, 1 for 1.0, 5e-05): the full check decides
            return self.finish(checked if self.builder is None else self.builder.decode(data))
        except (msgspec.MsgspecError, ProtocolError, UnicodeError):
            return None

    def finish(self, built: Any) -> Message:
        """The message from its built Struct: the fields msgspec could not state checked, the cross-field rules."""
        kwargs = msgspec.structs.asdict(built)
        for attr, finish in self.finishers:
            kwargs[attr] = finish(kwargs[attr])
        for attr, spec in self.own_checks:
            kwargs[attr] = spec.check(kwargs[attr], attr)
        msg = self.cls(**kwargs)
        msg._cross_check()
        return msg

    def encode(self, msg: Message) -> bytes | None:
        """``msg``'s bytes when msgspec writes it as the protocol does and they decode back to ``msg``, else None
        (a renamed field, numpy values, tuples, NaN written as null: ``Message.encode``'s full path decides)."""
        if not self.writes_itself:
            return None
        try:
            data = _ENCODER.encode(msg)
        except (TypeError, msgspec.MsgspecError):
            return None
        return data if len(data) <= self.cls.MAX_BYTES and self.decode(data) == msg else None


def _holds(spec: Any, kinds: type | tuple[type, ...]) -> bool:
    """Whether the spec is, or holds, a spec of these kinds."""
    if isinstance(spec, kinds):
        return True
    if isinstance(spec, Obj):
        return any(_holds(inner, kinds) for inner in spec.fields.values())
    inner = getattr(spec, "inner", None) or getattr(spec, "item", None) or getattr(spec, "value", None)
    return isinstance(inner, Spec) and _holds(inner, kinds)


_DECODERS: dict[type, FastDecoder] = {}


def fast_decoder(cls: type[Message]) -> FastDecoder:
    """The type's fast decoder, made on first use."""
    found = _DECODERS.get(cls)
    if found is None:
        found = _DECODERS[cls] = FastDecoder(cls)
    return found
