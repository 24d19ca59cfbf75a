"""Messages as JSON objects: the ``Message`` base class, and the engine that encodes and decodes them.

A message type is a frozen dataclass whose fields carry their specs (``fld``); the specs are the one definition
(schemas, docs/protocol.md, the Hypothesis strategies and the full check read them). Each type also gets a msgspec
decoder derived from its specs (``FastDecoder``; the derivation is in ``_fast.py``, made once per type), which
``Message.decode`` asks first and trusts only for a message in its canonical form (``encode``'s own bytes: compact,
every field present, each key once): any other input, valid or not, goes to the full check, which gives the result
and the reason. So what a decoder accepts, and why it rejects, does not depend on the engine; only how fast it
answers (a Step decodes 2-3x faster, a Credit about 4x: docs/notes/2026-11-28-msgspec.md).

The scalar specs, the base ``Spec`` and ``ProtocolError`` are in ``_spec.py``; the specs that hold others
(``List``, ``Map``, ``Nullable``, ``Obj``, ``Embedded``, ``AnyJSON``) and ``check_object`` in ``_containers.py``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import Any, ClassVar, cast

import msgspec

from ._containers import AnyJSON, Embedded, List, Map, Nullable, Obj, check_object
from ._spec import ProtocolError, QuickMiss, Spec

__all__ = [
    "PROTOCOL_VERSION",
    "AnyJSON",
    "Embedded",
    "List",
    "Map",
    "Message",
    "Nullable",
    "Obj",
    "FastDecoder",
    "WireField",
    "check_object",
    "encode_json",
    "fast_decoder",
    "fld",
    "parse_json",
]

#: Bumped when a wire format changes incompatibly. Written into every log's metadata and RunConfig.
PROTOCOL_VERSION = 1

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def fld(spec: Spec, *, wire: str | None = None, optional: bool = False, **kwargs: Any) -> Any:
    """A message field. ``wire`` renames it on the wire (``return`` is a Python keyword);
    ``optional`` fields may be absent on the wire and default to None."""
    if optional:
        kwargs.setdefault("default", None)
    return dataclasses.field(metadata={"spec": spec, "wire": wire, "optional": optional}, **kwargs)


@dataclasses.dataclass(frozen=True)
class WireField:
    attr: str
    wire: str
    spec: Spec
    optional: bool


def _reject_constant(name: str) -> Any:
    raise ProtocolError("non_finite", f"JSON literal {name}")


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise ProtocolError("malformed", "an object repeats a key")
    return out


# Made once: json.loads with options builds a new decoder at every call.
_STRICT_JSON = json.JSONDecoder(parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)


def parse_json(data: Any, max_bytes: int) -> Any:
    """Bytes -> JSON value, strictly: size first, UTF-8, no NaN/Infinity literals, no repeated keys."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ProtocolError("malformed", f"expected bytes, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise ProtocolError("oversized", f"{len(data)} bytes > limit {max_bytes}")
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError:
        raise ProtocolError("malformed", "not UTF-8") from None
    try:
        return _STRICT_JSON.decode(text)
    except ProtocolError:
        raise
    except (ValueError, RecursionError) as e:  # JSONDecodeError, int digits limit, deep nesting
        raise ProtocolError("malformed", f"not JSON: {str(e)[:80]}") from None


class Message:
    """Base of every message type. Subclasses are frozen dataclasses whose fields use :func:`fld`.

    ``encode()`` validates and returns compact UTF-8 JSON; ``decode(bytes)`` validates and returns an
    instance or raises :class:`ProtocolError`. Construction itself does not validate (it is cheap);
    ``validate()`` does, and so does ``encode()``.
    """

    TYPE_NAME: ClassVar[str] = ""  # schema name in MCAP, e.g. "hitl.Step"
    MAX_BYTES: ClassVar[int] = 4096  # size limit of the encoded message
    CONTENT_TYPE: ClassVar[str] = "application/json"
    MESSAGE_ENCODING: ClassVar[str] = "json"  # MCAP message encoding
    CROSS_RULES: ClassVar[tuple[str, ...]] = ()  # documentation of _cross_check
    # Per-class caches, made on first use (read through cls.__dict__, so a subclass never sees its base's).
    _wire_fields_cache: ClassVar[list[WireField]]
    _decode_tables_cache: ClassVar[tuple[dict[str, str], dict[str, Spec], set[str]]]

    # -- field table ---------------------------------------------------------------------------------
    @classmethod
    def wire_fields(cls) -> list[WireField]:
        cached = cls.__dict__.get("_wire_fields_cache")
        if cached is None:
            cached = [
                WireField(f.name, f.metadata.get("wire") or f.name, f.metadata["spec"], f.metadata["optional"])
                for f in dataclasses.fields(cast(Any, cls))  # (every subclass is a dataclass; Message is not)
            ]
            cls._wire_fields_cache = cached
        return cached

    @classmethod
    def _decode_tables(cls) -> tuple[dict[str, str], dict[str, Spec], set[str]]:
        """(wire name -> attribute, wire name -> spec, required wire names), made once per class."""
        cached = cls.__dict__.get("_decode_tables_cache")
        if cached is None:
            fields = cls.wire_fields()
            cached = (
                {wf.wire: wf.attr for wf in fields},
                {wf.wire: wf.spec for wf in fields},
                {wf.wire for wf in fields if not wf.optional},
            )
            cls._decode_tables_cache = cached
        return cached

    # -- JSON Schema ---------------------------------------------------------------------------------
    @classmethod
    def json_schema(cls) -> dict:
        props = {}
        for wf in cls.wire_fields():
            s = dict(wf.spec.schema())
            if wf.spec.description:
                s = {"description": wf.spec.description, **s}
            props[wf.wire] = s
        schema = {
            "$schema": SCHEMA_DIALECT,
            "$id": f"urn:hitl-tamer:protocol:{PROTOCOL_VERSION}:{cls.TYPE_NAME}",
            "title": cls.TYPE_NAME,
            "description": " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split()),
            "type": "object",
            "properties": props,
            "required": [wf.wire for wf in cls.wire_fields() if not wf.optional],
            "additionalProperties": False,
        }
        return schema

    # -- JSON object <-> instance ----------------------------------------------------------------------
    def to_json_obj(self) -> dict:
        return {wf.wire: wf.spec.to_json(getattr(self, wf.attr)) for wf in self.wire_fields()}

    @classmethod
    def from_json_obj(cls, obj: Any) -> Message:
        try:
            return cls.quick_from_json_obj(obj)
        except QuickMiss:  # (not plainly valid: the full check says why, or accepts what quick leaves to it)
            pass
        if not isinstance(obj, dict):
            raise ProtocolError("wrong_type", f"top level: expected object, got {type(obj).__name__}")
        attrs, specs, required = cls._decode_tables()
        values = check_object(obj, specs, required=required, path="")
        msg = cls(**{attrs[w]: v for w, v in values.items()})
        msg._cross_check()
        return msg

    @classmethod
    def quick_from_json_obj(cls, obj: Any) -> Message:
        """The message, when ``obj`` is plainly valid (every field's ``quick``), else ``QuickMiss``: the same
        result as the full check at a third of its cost (a Step is decoded by three services)."""
        attrs, specs, required = cls._decode_tables()
        if type(obj) is not dict or not required <= obj.keys() <= specs.keys():
            raise QuickMiss
        msg = cls(**{attrs[w]: specs[w].quick(v) for w, v in obj.items()})
        try:
            msg._cross_check()
        except ProtocolError:
            raise QuickMiss from None
        return msg

    def _cross_check(self) -> None:
        """Rules that involve several fields (documented in CROSS_RULES). Raise ProtocolError."""

    # -- bytes -------------------------------------------------------------------------------------------
    def encode(self) -> bytes:
        data = fast_decoder(type(self)).encode(self)  # (msgspec writes the usual message, checked by decoding it back)
        if data is not None:
            return data
        obj = self.to_json_obj()
        # Validate exactly what goes on the wire, with the decoder's own checks, so encode never emits
        # something that decode would reject.
        type(self).from_json_obj(obj)
        return self._dump(obj)

    def encode_checked(self) -> bytes:
        """``encode()`` of a message that came out of ``decode`` (every field and rule already checked, e.g. a
        Credit carried in an Ingest): the same bytes, without checking the fields again; the size still is."""
        return self._dump(self.to_json_obj())

    def _dump(self, obj: dict) -> bytes:
        # msgspec's spelling of numbers (the form the fast decoders take); finite: checked by encode, or decoded
        data = encode_json(obj)
        if len(data) > self.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {self.MAX_BYTES}")
        return data

    @classmethod
    def decode(cls, data: bytes) -> Message:
        if type(data) is bytes and len(data) <= cls.MAX_BYTES:
            msg = fast_decoder(cls).decode(data)
            if msg is not None:
                return msg
        return cls.from_json_obj(parse_json(data, cls.MAX_BYTES))

    def validate(self) -> None:
        self.encode()


# -- the engine: msgspec's decoder and encoder for each message type's usual form ------------------------------------

_ENCODER = msgspec.json.Encoder()
#: Every JSON value written by ``Message.encode`` (a dict of plain Python values, already checked: finite numbers).
encode_json: Callable[[Any], bytes] = _ENCODER.encode
Convert = Callable[[Any], Any]


class FastDecoder:
    """One message type's msgspec decoder. ``decode`` gives the message for canonical valid bytes, else None.

    Two passes in C: the first checks every stated constraint and that the bytes are canonical, the second builds
    the values (nested dataclasses and embedded messages included). A top-level field whose spec msgspec cannot
    state (the run config, an image's base64) is any JSON in both and goes through its spec's own check."""

    def __init__(self, cls: type[Message]):
        from ._fast import msgspec_types  # (derived once per type, off a step's path)

        self.cls = cls
        types = msgspec_types(cls)
        self.own_checks, self.finishers, self.writes_itself = types.own_checks, types.finishers, types.writes_itself
        self.checked_type, self.built_type = types.checked, types.built
        self.checker = msgspec.json.Decoder(types.checked)
        self.builder = None if types.built is types.checked else msgspec.json.Decoder(types.built)

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


_DECODERS: dict[type, FastDecoder] = {}


def fast_decoder(cls: type[Message]) -> FastDecoder:
    """The type's fast decoder, made on first use."""
    found = _DECODERS.get(cls)
    if found is None:
        found = _DECODERS[cls] = FastDecoder(cls)
    return found
