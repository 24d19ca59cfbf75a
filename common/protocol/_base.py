"""The ``Message`` base class: JSON encode/decode driven by the field specs."""

from __future__ import annotations

import dataclasses
import json
from typing import Any, ClassVar, cast

from ._containers import check_object
from ._spec import ProtocolError, Spec

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
        return json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)
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
        if not isinstance(obj, dict):
            raise ProtocolError("wrong_type", f"top level: expected object, got {type(obj).__name__}")
        attrs, specs, required = cls._decode_tables()
        values = check_object(obj, specs, required=required, path="")
        msg = cls(**{attrs[w]: v for w, v in values.items()})
        msg._cross_check()
        return msg

    def _cross_check(self) -> None:
        """Rules that involve several fields (documented in CROSS_RULES). Raise ProtocolError."""

    # -- bytes -------------------------------------------------------------------------------------------
    def encode(self) -> bytes:
        obj = self.to_json_obj()
        # Validate exactly what goes on the wire, with the decoder's own checks, so encode never emits
        # something that decode would reject.
        type(self).from_json_obj(obj)
        data = json.dumps(obj, separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode("utf-8")
        if len(data) > self.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {self.MAX_BYTES}")
        return data

    @classmethod
    def decode(cls, data: bytes) -> Message:
        return cls.from_json_obj(parse_json(data, cls.MAX_BYTES))

    def validate(self) -> None:
        self.encode()
