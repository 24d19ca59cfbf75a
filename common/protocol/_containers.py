"""The specs that hold other values: ``List``, ``Map``, ``Nullable``, ``Obj``, a whole message of another type
nested as an object (``Embedded``) and any JSON value (``AnyJSON``, the run config); and ``check_object``, which
validates the fields of a message or of a nested ``Obj``. Each has the full ``check`` and a ``quick`` that accepts
ordinary valid input at once (``_spec.Spec``). None of them runs on a step's path: the msgspec engine in ``_base.py``
decodes a message in its usual form, and these only check what it leaves to them."""

from __future__ import annotations

import math
from typing import Any

from ._spec import ProtocolError, QuickMiss, Spec, _check_text, _type_name


class Embedded(Spec):
    """A whole message of another type as a nested object: its own fields, checks and cross-rules. ``message``
    returns the class (a function, so that a module may name a message type defined after it)."""

    def __init__(self, message: Any, *, description: str = ""):
        self._message = message
        self.description = description

    @property
    def cls(self) -> Any:
        return self._message()

    def schema(self) -> dict:
        return {k: v for k, v in self.cls.json_schema().items() if k not in ("$schema", "$id")}

    def check(self, value: Any, path: str) -> Any:
        try:
            return self.cls.from_json_obj(value)
        except ProtocolError as e:
            raise ProtocolError(e.reason, f"{path}: {e.detail}") from None

    def quick(self, value: Any) -> Any:
        return self.cls.quick_from_json_obj(value)

    def to_json(self, value: Any) -> Any:
        return value.to_json_obj() if isinstance(value, self.cls) else value

    def describe(self) -> str:
        return f"a `{self.cls.TYPE_NAME}` object (its own fields and rules)"


class AnyJSON(Spec):
    """Any JSON value with finite numbers, bounded nesting depth. Used for the run config."""

    def __init__(self, *, max_depth: int = 32, object_only: bool = False, description: str = ""):
        self.max_depth, self.object_only = max_depth, object_only
        self.description = description

    def schema(self) -> dict:
        return {"type": "object"} if self.object_only else {}

    def check(self, value: Any, path: str) -> Any:
        if self.object_only and not isinstance(value, dict):
            raise ProtocolError("wrong_type", f"{path}: expected object, got {_type_name(value)}")
        self._walk(value, path, 0)
        return value

    def _walk(self, value: Any, path: str, depth: int) -> None:
        if depth > self.max_depth:
            raise ProtocolError("bad_value", f"{path}: nested deeper than {self.max_depth}")
        if isinstance(value, float):
            if not math.isfinite(value):
                raise ProtocolError("non_finite", path)
        elif isinstance(value, str):
            _check_text(value, path)
        elif isinstance(value, dict):
            for k, v in value.items():
                if not isinstance(k, str):
                    raise ProtocolError("wrong_type", f"{path}: object key {k!r} is not a string")
                _check_text(k, path)
                self._walk(v, f"{path}.{k}", depth + 1)
        elif isinstance(value, list):
            for i, v in enumerate(value):
                self._walk(v, f"{path}[{i}]", depth + 1)
        elif value is not None and not isinstance(value, (bool, int)):
            raise ProtocolError("wrong_type", f"{path}: {type(value).__name__} is not JSON")

    def describe(self) -> str:
        return ("object" if self.object_only else "any JSON value") + f", finite numbers, depth <= {self.max_depth}"


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
