"""Messages as JSON objects: the ``Message`` base class (JSON encode/decode driven by the field specs).

Here too the specs that hold other specs (``List``, ``Map``, ``Nullable``, ``Obj``) and ``check_object``, which
validates the fields of a message or of a nested ``Obj``; each has the full ``check`` and a ``quick`` that accepts
ordinary valid input at once (``_spec.Spec``). The scalar specs, the base ``Spec`` and ``ProtocolError`` are in
``_spec.py``; ``Embedded`` and ``AnyJSON`` in ``_whole.py`` (they are off a step's path).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, ClassVar, cast

from ._spec import ProtocolError, QuickMiss, Spec, _check_text, _type_name
from ._whole import AnyJSON, Embedded

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
        from ._fast import fast_decoder  # (msgspec writes the usual message and checks it by decoding it back)

        data = fast_decoder(type(self)).encode(self)
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
        from ._fast import encode_json  # (msgspec's spelling of numbers: the form the fast decoders take)

        data = encode_json(obj)  # (finite: checked by encode, or decoded; msgspec would write NaN as null)
        if len(data) > self.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {self.MAX_BYTES}")
        return data

    @classmethod
    def decode(cls, data: bytes) -> Message:
        if type(data) is bytes and len(data) <= cls.MAX_BYTES:
            from ._fast import fast_decoder  # (msgspec's decoder for the usual form; the full check for the rest)

            msg = fast_decoder(cls).decode(data)
            if msg is not None:
                return msg
        return cls.from_json_obj(parse_json(data, cls.MAX_BYTES))

    def validate(self) -> None:
        self.encode()


# -- the specs that hold other specs ---------------------------------------------------------------------------


class List(Spec):
    def __init__(self, item: Spec, *, max_items: int, min_items: int = 0, description: str = ""):
        self.item, self.max_items, self.min_items = item, max_items, min_items
        self.description = description

    def schema(self) -> dict:
        s: dict[str, Any] = {"type": "array", "items": self.item.schema(), "maxItems": self.max_items}
        if self.min_items:
            s["minItems"] = self.min_items
        return s

    def check(self, value: Any, path: str) -> list:
        if not isinstance(value, list):
            raise ProtocolError("wrong_type", f"{path}: expected array, got {_type_name(value)}")
        if not self.min_items <= len(value) <= self.max_items:
            raise ProtocolError("bad_value", f"{path}: {len(value)} items, not in [{self.min_items}, {self.max_items}]")
        check = self.item.check
        try:  # (the item's path is only spelled out for the error: checks are pure, so the second pass fails alike)
            return [check(v, path) for v in value]
        except ProtocolError:
            return [check(v, f"{path}[{i}]") for i, v in enumerate(value)]

    def quick(self, value: Any) -> list:
        if type(value) is not list or not self.min_items <= len(value) <= self.max_items:
            raise QuickMiss
        quick = self.item.quick
        return [quick(v) for v in value]

    def to_json(self, value: Any) -> Any:
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
            return value  # let check() report the wrong type
        return [self.item.to_json(v) for v in value]

    def describe(self) -> str:
        return f"array of ({self.item.describe()}), {self.min_items}..{self.max_items} items"


class Map(Spec):
    """A JSON object used as a dictionary: string keys (bounded) to values of one spec."""

    def __init__(self, value: Spec, *, max_items: int, key_max_len: int = 64, description: str = ""):
        self.value, self.max_items, self.key_max_len = value, max_items, key_max_len
        self.description = description

    def schema(self) -> dict:
        return {
            "type": "object",
            "additionalProperties": self.value.schema(),
            "propertyNames": {"minLength": 1, "maxLength": self.key_max_len},
            "maxProperties": self.max_items,
        }

    def check(self, value: Any, path: str) -> dict:
        if not isinstance(value, dict):
            raise ProtocolError("wrong_type", f"{path}: expected object, got {_type_name(value)}")
        if len(value) > self.max_items:
            raise ProtocolError("bad_value", f"{path}: {len(value)} entries, more than {self.max_items}")
        out = {}
        for k, v in value.items():
            _check_text(k, path)
            if not 1 <= len(k) <= self.key_max_len:
                raise ProtocolError("bad_value", f"{path}: key length {len(k)} not in [1, {self.key_max_len}]")
            out[k] = self.value.check(v, f"{path}.{k}")
        return out

    def quick(self, value: Any) -> dict:
        if type(value) is not dict or len(value) > self.max_items:
            raise QuickMiss
        quick, longest = self.value.quick, self.key_max_len
        for k in value:
            if not (k.isascii() and 1 <= len(k) <= longest):
                raise QuickMiss
        return {k: quick(v) for k, v in value.items()}

    def to_json(self, value: Any) -> Any:
        if not isinstance(value, dict):
            return value
        return {k: self.value.to_json(v) for k, v in value.items()}

    def describe(self) -> str:
        return (
            f"object of string (1..{self.key_max_len} chars) to ({self.value.describe()}), "
            f"at most {self.max_items} entries"
        )


class Nullable(Spec):
    def __init__(self, inner: Spec, *, description: str = ""):
        self.inner = inner
        self.description = description or inner.description

    def schema(self) -> dict:
        return {"anyOf": [self.inner.schema(), {"type": "null"}]}

    def check(self, value: Any, path: str) -> Any:
        return None if value is None else self.inner.check(value, path)

    def quick(self, value: Any) -> Any:
        return None if value is None else self.inner.quick(value)

    def to_json(self, value: Any) -> Any:
        return None if value is None else self.inner.to_json(value)

    def describe(self) -> str:
        return f"null or {self.inner.describe()}"


class Obj(Spec):
    """A nested JSON object with fixed fields (all required, no extras).

    With ``cls`` (a dataclass whose fields have the same names) the Python value is an instance of it,
    otherwise a dict.
    """

    def __init__(self, fields: dict[str, Spec], *, cls: type | None = None, description: str = ""):
        self.fields = fields
        self.required = set(fields)
        self.cls = cls
        self.description = description

    def schema(self) -> dict:
        return {
            "type": "object",
            "properties": {k: v.schema() for k, v in self.fields.items()},
            "required": list(self.fields),
            "additionalProperties": False,
        }

    def check(self, value: Any, path: str) -> dict:
        if not isinstance(value, dict):
            raise ProtocolError("wrong_type", f"{path}: expected object, got {_type_name(value)}")
        out = check_object(value, self.fields, required=self.required, path=path)
        return self.cls(**out) if self.cls is not None else out

    def quick(self, value: Any) -> Any:
        if type(value) is not dict or value.keys() != self.required:
            raise QuickMiss
        out = {k: spec.quick(value[k]) for k, spec in self.fields.items()}
        return self.cls(**out) if self.cls is not None else out

    def to_json(self, value: Any) -> Any:
        if self.cls is not None and isinstance(value, self.cls):
            return {k: spec.to_json(getattr(value, k)) for k, spec in self.fields.items()}
        if isinstance(value, dict):
            return {k: (self.fields[k].to_json(v) if k in self.fields else v) for k, v in value.items()}
        return value

    def describe(self) -> str:
        return "object {" + ", ".join(f"{k}: {v.describe()}" for k, v in self.fields.items()) + "}"


def check_object(value: dict, fields: dict[str, Spec], *, required: set[str], path: str) -> dict:
    """Validate a JSON object against named field specs; return {name: python value}."""
    if not fields.keys() >= value.keys():  # (set operations first: the loops below only name the culprit)
        extra = [k for k in value if k not in fields]
        raise ProtocolError("extra_field", f"{path}: unexpected field {str(extra[0])[:40]!r}")
    if not required <= value.keys():
        for name in fields:
            if name in required and name not in value:
                raise ProtocolError("missing_field", f"{path}.{name}" if path else name)
    prefix = f"{path}." if path else ""
    return {name: spec.check(value[name], prefix + name) for name, spec in fields.items() if name in value}
