"""Field specifications: one definition gives the JSON Schema, the validator and the docs.

Each message field carries a ``Spec`` in its dataclass metadata. A spec can
``check(value, path)`` a value parsed from JSON (raising ``ProtocolError`` with a
machine-readable reason), ``schema()`` a JSON Schema (draft 2020-12) fragment,
``to_json``/``from_json`` convert between the Python value and its JSON form, and
``describe()`` a short human description for docs/protocol.md.

This module holds the errors, the base ``Spec`` and the scalar specs; the specs that nest others (``List``,
``Map``, ``Nullable``, ``Obj``, ``Embedded``, ``AnyJSON``) and ``check_object`` are in ``_containers.py``.

Nothing here imports zenoh or mcap: the protocol is usable by the pure core and by tests.
"""

from __future__ import annotations

import base64
import binascii
import math
import numbers
import re
from typing import Any

import numpy as np

#: Integers on the wire stay inside the range that a double represents exactly, so that a
#: JSON reader in any language (Foxglove is JavaScript) reads them back unchanged.
SAFE_INT = 2**53 - 1

#: Every reason a decoder may give. Subscribers count drops per reason.
REASONS: dict[str, str] = {
    "malformed": "bytes are not UTF-8 JSON (or not a safetensors file), or a JSON object repeats a key",
    "oversized": "payload larger than the type's size limit (checked before parsing)",
    "wrong_type": "a value has the wrong JSON type (e.g. string for integer, bool for integer, non-object top level)",
    "missing_field": "a required field is absent",
    "extra_field": "a field that the type does not define is present",
    "non_finite": "a number is NaN or +-Infinity (including overflowing literals such as 1e999)",
    "bad_value": "right type, but out of range, not an allowed value, bad pattern, too long, bad base64",
    "bad_shape": "a list has the wrong length relative to another field, or a tensor has the wrong name/dtype/shape",
    "unknown_key": "a key expression that the protocol does not define",
}


class ProtocolError(ValueError):
    """A message could not be encoded or decoded.

    ``reason`` is one of :data:`REASONS` (short, machine-readable, for drop counters);
    ``detail`` says which field and why, for humans.
    """

    def __init__(self, reason: str, detail: str = ""):
        if reason not in REASONS:  # a programming error in this package, not bad input
            raise AssertionError(f"unknown ProtocolError reason {reason!r}")
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "object"
    return type(value).__name__


def _check_text(value: str, path: str) -> None:
    # Lone surrogates can come out of JSON "\ud800" escapes; they cannot be encoded as UTF-8.
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise ProtocolError("bad_value", f"{path}: string is not valid Unicode") from None


class QuickMiss(Exception):
    """A quick check (``Spec.quick``) could not accept a value at once: the full check decides (and names the error).
    Raised as a new instance each time: one shared instance would gather the frames of every raise in its
    traceback, for the life of the process."""


class Spec:
    """Base class of field specifications.

    ``check`` is the full validation (it names the field and the reason of a rejection); ``quick`` accepts the
    ordinary case of valid input faster and gives the same value as ``check``, else raises ``QuickMiss`` (never
    ``ProtocolError``), after which the caller runs ``check`` on the whole message."""

    description: str = ""

    def schema(self) -> dict:
        raise NotImplementedError

    def check(self, value: Any, path: str) -> Any:
        """Validate a JSON value; return the Python value."""
        raise NotImplementedError

    def quick(self, value: Any) -> Any:
        try:
            return self.check(value, "")
        except ProtocolError:
            raise QuickMiss from None

    def to_json(self, value: Any) -> Any:
        return value

    def describe(self) -> str:
        raise NotImplementedError


class Str(Spec):
    def __init__(
        self,
        max_len: int = 256,
        *,
        pattern: str | None = None,
        enum: tuple[str, ...] | None = None,
        min_len: int = 0,
        description: str = "",
    ):
        self.max_len, self.min_len, self.pattern, self.enum = max_len, min_len, pattern, enum
        # Patterns are written anchored with ^...$ (ECMA-262 style, as JSON Schema reads them). Python's `$`
        # also matches before a final newline, so the validator uses \Z in its place.
        self._re = re.compile(pattern[:-1] + r"\Z" if pattern.endswith("$") else pattern) if pattern else None
        self.description = description

    def schema(self) -> dict:
        s: dict[str, Any] = {"type": "string"}
        if self.enum is not None:
            s["enum"] = list(self.enum)
            return s
        if self.min_len:
            s["minLength"] = self.min_len
        s["maxLength"] = self.max_len
        if self.pattern:
            s["pattern"] = self.pattern
        return s

    def check(self, value: Any, path: str) -> str:
        if not isinstance(value, str):
            raise ProtocolError("wrong_type", f"{path}: expected string, got {_type_name(value)}")
        _check_text(value, path)
        if self.enum is not None:
            if value not in self.enum:
                raise ProtocolError("bad_value", f"{path}: {value[:40]!r} not one of {list(self.enum)}")
            return value
        if not self.min_len <= len(value) <= self.max_len:
            raise ProtocolError("bad_value", f"{path}: length {len(value)} not in [{self.min_len}, {self.max_len}]")
        if self._re is not None and not self._re.search(value):
            raise ProtocolError("bad_value", f"{path}: {value[:40]!r} does not match {self.pattern}")
        return value

    def quick(self, value: Any) -> str:
        # (ASCII text holds no lone surrogate: the UTF-8 check is left to the full check for the rest)
        if type(value) is not str or not value.isascii():
            raise QuickMiss
        if self.enum is not None:
            if value in self.enum:
                return value
            raise QuickMiss
        if self.min_len <= len(value) <= self.max_len and (self._re is None or self._re.search(value)):
            return value
        raise QuickMiss

    def describe(self) -> str:
        if self.enum is not None:
            return "string, one of " + ", ".join(f"`{e}`" for e in self.enum)
        d = f"string, length {self.min_len}..{self.max_len}"
        if self.pattern:
            d += f", pattern `{self.pattern}`"
        return d


class Int(Spec):
    def __init__(
        self,
        minimum: int = -SAFE_INT,
        maximum: int = SAFE_INT,
        *,
        enum: tuple[int, ...] | None = None,
        description: str = "",
    ):
        self.minimum, self.maximum, self.enum = minimum, maximum, enum
        self.description = description

    def schema(self) -> dict:
        if self.enum is not None:
            return {"type": "integer", "enum": list(self.enum)}
        return {"type": "integer", "minimum": self.minimum, "maximum": self.maximum}

    def check(self, value: Any, path: str) -> int:
        # JSON Schema's "integer" admits 1.0; so do we (normalised to int). bool is never an integer.
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ProtocolError("wrong_type", f"{path}: expected integer, got {_type_name(value)}")
        if isinstance(value, float):
            if not math.isfinite(value):
                raise ProtocolError("non_finite", f"{path}: {value}")
            if not value.is_integer():
                raise ProtocolError("wrong_type", f"{path}: expected integer, got {value!r}")
            if abs(value) > SAFE_INT:
                raise ProtocolError("bad_value", f"{path}: {value!r} out of range")
            value = int(value)
        if self.enum is not None:
            if value not in self.enum:
                raise ProtocolError("bad_value", f"{path}: {value} not one of {list(self.enum)}")
        elif not self.minimum <= value <= self.maximum:
            raise ProtocolError("bad_value", f"{path}: {value} not in [{self.minimum}, {self.maximum}]")
        return value

    def quick(self, value: Any) -> int:
        if type(value) is int and (
            self.minimum <= value <= self.maximum if self.enum is None else value in self.enum
        ):  # (an integer written 1.0 goes to the full check, which reads it as 1)
            return value
        raise QuickMiss

    def to_json(self, value: Any) -> Any:
        if type(value) is int:
            return value
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            return int(value)  # numpy integers
        return value

    def describe(self) -> str:
        if self.enum is not None:
            return "integer, one of " + ", ".join(str(e) for e in self.enum)
        lo = "" if self.minimum == -SAFE_INT else str(self.minimum)
        hi = "" if self.maximum == SAFE_INT else str(self.maximum)
        if not lo and not hi:
            return "integer (|x| < 2^53)"
        return f"integer in [{lo or '-2^53+1'}, {hi or '2^53-1'}]"


class Float(Spec):
    def __init__(self, minimum: float | None = None, maximum: float | None = None, *, description: str = ""):
        self.minimum, self.maximum = minimum, maximum
        self.description = description
        self._low = -math.inf if minimum is None else minimum
        self._high = math.inf if maximum is None else maximum
        self._bounded = math.isfinite(self._low) and math.isfinite(self._high)

    def schema(self) -> dict:
        s: dict[str, Any] = {"type": "number"}
        if self.minimum is not None:
            s["minimum"] = self.minimum
        if self.maximum is not None:
            s["maximum"] = self.maximum
        return s

    def check(self, value: Any, path: str) -> float:
        if type(value) is float and self.minimum is None and self.maximum is None and math.isfinite(value):
            return value  # (the common case, decided at once)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ProtocolError("wrong_type", f"{path}: expected number, got {_type_name(value)}")
        try:
            value = float(value)
        except OverflowError:  # an integer literal too large for a double
            raise ProtocolError("non_finite", f"{path}: integer too large for a double") from None
        if not math.isfinite(value):
            raise ProtocolError("non_finite", f"{path}: {value}")
        if (self.minimum is not None and value < self.minimum) or (self.maximum is not None and value > self.maximum):
            raise ProtocolError("bad_value", f"{path}: {value!r} not in [{self.minimum}, {self.maximum}]")
        return value

    def quick(self, value: Any) -> float:
        # (NaN fails every comparison; -inf/+inf fail the finite bounds, or the isfinite test without bounds)
        if type(value) is float and self._low <= value <= self._high and (self._bounded or math.isfinite(value)):
            return value
        raise QuickMiss  # (an integer goes to the full check, which makes it a float)

    def to_json(self, value: Any) -> Any:
        if type(value) is float:
            return value
        if isinstance(value, numbers.Real) and not isinstance(value, (bool, numbers.Integral)):
            return float(value)  # numpy floats
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            return int(value)
        return value

    def describe(self) -> str:
        if self.minimum is None and self.maximum is None:
            return "number, finite"
        lo = "-inf" if self.minimum is None else repr(self.minimum)
        hi = "+inf" if self.maximum is None else repr(self.maximum)
        return f"number, finite, in [{lo}, {hi}]"


class Bool(Spec):
    def __init__(self, *, description: str = ""):
        self.description = description

    def schema(self) -> dict:
        return {"type": "boolean"}

    def check(self, value: Any, path: str) -> bool:
        if not isinstance(value, bool):
            raise ProtocolError("wrong_type", f"{path}: expected boolean, got {_type_name(value)}")
        return value

    def quick(self, value: Any) -> bool:
        if type(value) is bool:
            return value
        raise QuickMiss

    def to_json(self, value: Any) -> Any:
        if isinstance(value, np.bool_):
            return bool(value)
        return value

    def describe(self) -> str:
        return "boolean"


#: Canonical standard base64 (what `b64encode` writes: padded, unused bits zero), in the schema and the decoder
#: alike. `(?![\s\S])` ends the string in every regex dialect (Python's `$` also matches before a newline).
BASE64_PATTERN = (
    r"^(?:[A-Za-z0-9+/]{4})*(?:[A-Za-z0-9+/][AQgw]==|[A-Za-z0-9+/]{2}[AEIMQUYcgkosw048]=)?"
    r"(?![\s\S])"
)
_BASE64_RE = re.compile(BASE64_PATTERN)


class Bytes64(Spec):
    """Binary data carried as a standard base64 string (as foxglove.CompressedImage does in JSON)."""

    def __init__(self, max_bytes: int, *, description: str = ""):
        self.max_bytes = max_bytes
        self.description = description

    def schema(self) -> dict:
        return {
            "type": "string",
            "contentEncoding": "base64",
            "pattern": BASE64_PATTERN,
            "maxLength": 4 * ((self.max_bytes + 2) // 3),
        }

    def check(self, value: Any, path: str) -> bytes:
        if not isinstance(value, str):
            raise ProtocolError("wrong_type", f"{path}: expected base64 string, got {_type_name(value)}")
        if len(value) > 4 * ((self.max_bytes + 2) // 3):
            raise ProtocolError("bad_value", f"{path}: longer than {self.max_bytes} bytes")
        if not _BASE64_RE.match(value):
            raise ProtocolError("bad_value", f"{path}: not canonical standard base64")
        try:
            return base64.b64decode(value.encode("ascii"), validate=True)
        except (binascii.Error, UnicodeEncodeError, ValueError):
            raise ProtocolError("bad_value", f"{path}: not standard base64") from None

    def to_json(self, value: Any) -> str:
        return base64.b64encode(bytes(value)).decode("ascii")

    def describe(self) -> str:
        return f"bytes as a standard base64 string (at most {self.max_bytes} bytes)"
