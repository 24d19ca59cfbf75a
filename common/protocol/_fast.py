"""How the msgspec engine (``FastDecoder`` in ``_base.py``) gets its types: from the same field specs, once per message
type. Each type gets two frozen Structs: one that states every constraint the specs state (checked in C), and, when
a field nests an object or a message, one that builds the nested dataclasses themselves. A spec msgspec cannot state
(``AnyJSON``, ``Bytes64``) becomes ``Any`` there and is checked by its own ``check`` in Python.

Why the engine trusts only the canonical form: msgspec keeps the last of repeated keys (the protocol rejects them),
reads 1 as a float and writes NaN as null. Bytes that equal msgspec's encoding of what it decoded have none of
those: each key once, every number in the form it has.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from ._base import Convert, Message, fast_decoder
from ._containers import Embedded, List, Map, Nullable, Obj
from ._spec import Bool, Float, Int, Spec, Str

__all__ = ["MsgspecTypes", "msgspec_types"]


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


def _holds(spec: Any, kinds: type | tuple[type, ...]) -> bool:
    """Whether the spec is, or holds, a spec of these kinds."""
    if isinstance(spec, kinds):
        return True
    if isinstance(spec, Obj):
        return any(_holds(inner, kinds) for inner in spec.fields.values())
    inner = getattr(spec, "inner", None) or getattr(spec, "item", None) or getattr(spec, "value", None)
    return isinstance(inner, Spec) and _holds(inner, kinds)


@dataclasses.dataclass(frozen=True)
class MsgspecTypes:
    """A message type's Structs and what its engine does in Python after them."""

    checked: Any  # states every constraint; decodes the usual form in C
    built: Any  # builds the values (nested dataclasses, embedded messages); ``checked`` itself without nesting
    own_checks: list[tuple[str, Any]]  # (attribute, spec) of top-level fields msgspec cannot state
    finishers: list[tuple[str, Convert]]  # (attribute, how to turn its built value into the message's)
    writes_itself: bool  # msgspec writes attribute names: with a renamed field (``return_``), the full way


def msgspec_types(cls: type[Message]) -> MsgspecTypes:
    """The Structs of a message type, derived from its field specs."""
    fields = cls.wire_fields()
    optional = {wf.attr for wf in fields if wf.optional}
    own_checks: list[tuple[str, Any]] = []
    finishers: list[tuple[str, Convert]] = []
    checked, built = [], []
    for wf in fields:
        try:
            finish = _finisher(wf.spec)
            checked.append((wf.attr, wf.wire, _checked(wf.spec)))
            built.append((wf.attr, wf.wire, _built(wf.spec)))
            if finish is not None:
                finishers.append((wf.attr, finish))
        except Unstated:
            checked.append((wf.attr, wf.wire, Any))
            built.append((wf.attr, wf.wire, Any))
            own_checks.append((wf.attr, wf.spec))
    name = cls.TYPE_NAME.replace(".", "_")
    checked_type = _struct(name, checked, optional=optional)
    # (without a nested object the checked values are the built ones: one pass)
    nested = any(_holds(wf.spec, (Obj, Embedded)) for wf in fields)
    built_type = _struct(name, built, optional=optional) if nested else checked_type
    writes_itself = all(wf.wire == wf.attr for wf in fields)
    return MsgspecTypes(checked_type, built_type, own_checks, finishers, writes_itself)
