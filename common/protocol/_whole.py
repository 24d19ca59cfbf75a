"""The specs of whole values: a whole message of another type nested as an object (``Embedded``), and any JSON value
(``AnyJSON``, the run config). The other specs that hold specs are in ``_base.py``, with ``Message``."""

from __future__ import annotations

import math
from typing import Any

from ._spec import ProtocolError, Spec, _check_text, _type_name


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
