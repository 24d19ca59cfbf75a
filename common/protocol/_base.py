"""Messages as JSON objects: the ``Message`` base class (JSON encode/decode driven by the field specs).

The scalar specs, the base ``Spec`` and ``ProtocolError`` are in ``_spec.py``; the specs that hold other specs
(``List``, ``Map``, ``Nullable``, ``Obj``, ``Embedded``, ``AnyJSON``) and ``check_object`` in ``_nested.py``.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, ClassVar, cast

from ._nested import AnyJSON, Embedded, List, Map, Nullable, Obj, check_object
from ._spec import QUICK_MISS, ProtocolError, QuickMiss, Spec

__all__ = [
    "PROTOCOL_VERSION",
    "AnyJSON",
    "Embedded",
    "List",
    "Map",
    "Message",
    "Nullable",
    "Obj",
    "WireField",
    "check_object",
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


# Made once: json.loads and json.dumps with options build a new decoder or encoder at every call.
_STRICT_JSON = json.JSONDecoder(parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)
_COMPACT_JSON = json.JSONEncoder(separators=(",", ":"), allow_nan=False, ensure_ascii=False)


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
            raise QUICK_MISS
        msg = cls(**{attrs[w]: specs[w].quick(v) for w, v in obj.items()})
        try:
            msg._cross_check()
        except ProtocolError:
            raise QUICK_MISS from None
        return msg

    def _cross_check(self) -> None:
        """Rules that involve several fields (documented in CROSS_RULES). Raise ProtocolError."""

    # -- bytes -------------------------------------------------------------------------------------------
    def encode(self) -> bytes:
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
        try:
            data = _COMPACT_JSON.encode(obj).encode("utf-8")
        except ValueError as e:  # NaN or infinity left in a field the checks did not see
            raise ProtocolError("non_finite", str(e)[:80]) from None
        if len(data) > self.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {self.MAX_BYTES}")
        return data

    @classmethod
    def decode(cls, data: bytes) -> Message:
        return cls.from_json_obj(parse_json(data, cls.MAX_BYTES))

    def validate(self) -> None:
        self.encode()
