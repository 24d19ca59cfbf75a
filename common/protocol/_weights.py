"""``Weights``: versioned float32 tensors in the safetensors format (never pickle).

Layout (safetensors): 8-byte little-endian header length N, N bytes of JSON header, then raw
little-endian tensor data. The header's ``__metadata__`` (string to string) carries the scalar fields;
every other header entry is a tensor ``{"dtype": "F32", "shape": [...], "data_offsets": [a, b]}``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import struct
from typing import Any, ClassVar
from collections.abc import Mapping

import numpy as np

from ._base import PROTOCOL_VERSION, parse_json
from ._fields import NAME_PATTERN, TOKEN_PATTERN
from ._spec import SAFE_INT, ProtocolError

TENSOR_NAME_PATTERN = r"^[A-Za-z0-9_.]{1,128}$"
_TENSOR_NAME_RE = re.compile(TENSOR_NAME_PATTERN[:-1] + r"\Z")
_NAME_RE = re.compile(NAME_PATTERN[:-1] + r"\Z")
_TOKEN_RE = re.compile(TOKEN_PATTERN[:-1] + r"\Z")
_FLOAT_RE = re.compile(r"[0-9]{1,20}(\.[0-9]{1,20})?([eE][+-]?[0-9]{1,4})?")
MAX_TENSORS = 64
MAX_NDIM = 8
MAX_HEADER = 64 * 1024
FORMAT_TAG = "hitl.Weights"

#: The metadata keys and what they hold (all values are strings in safetensors metadata).
METADATA_FIELDS = {
    "format": f"always `{FORMAT_TAG}`",
    "protocol": f"protocol version, `{PROTOCOL_VERSION}`",
    "run": "run name (pattern as Step.run)",
    "incarnation": "the learner process's own id (pattern as Step.incarnation)",
    "version": "weights version, decimal integer >= 0, increasing per learner incarnation",
    "t_published": "wall-clock time (s) of publication, a finite non-negative decimal number",
}
#: Metadata keys a Weights message may omit (older logs have none); same string rules as the others.
OPTIONAL_METADATA_FIELDS = {
    "revision": (
        "weights revision, decimal integer >= 0: the learner's count of Q and H updates, moved by every one "
        "(a credited press's H update too, between two steps); an actor takes weights newer in (version, "
        "revision)"
    ),
}

Spec = Mapping[str, tuple[int, ...]]


@dataclasses.dataclass(frozen=True, eq=False)
class Weights:
    """Versioned network weights from the learner (published on `hitl/<run>/weights`): named float32
    tensors in the safetensors format, with the scalar fields in its metadata. Decoding never unpickles."""

    TYPE_NAME: ClassVar[str] = "hitl.Weights"
    MAX_BYTES: ClassVar[int] = 32 * 1024 * 1024
    CONTENT_TYPE: ClassVar[str] = "application/octet-stream"
    MESSAGE_ENCODING: ClassVar[str] = "safetensors"

    run: str
    incarnation: str
    version: int
    t_published: float
    tensors: dict[str, np.ndarray]
    revision: int | None = None

    # -- encode -------------------------------------------------------------------------------------------
    def encode(self) -> bytes:
        import safetensors.numpy

        meta = self._metadata()
        tensors = {}
        if not isinstance(self.tensors, Mapping):
            raise ProtocolError("wrong_type", "tensors: expected a mapping of name to array")
        if len(self.tensors) > MAX_TENSORS:
            raise ProtocolError("bad_value", f"tensors: more than {MAX_TENSORS}")
        for name, arr in self.tensors.items():
            _check_tensor_name(name)
            a = np.asarray(arr)
            if a.dtype != np.float32:
                raise ProtocolError("bad_shape", f"{name}: dtype {a.dtype}, expected float32")
            if a.ndim > MAX_NDIM:
                raise ProtocolError("bad_shape", f"{name}: {a.ndim} dimensions > {MAX_NDIM}")
            if not np.isfinite(a).all():
                raise ProtocolError("non_finite", f"{name}: contains NaN or Inf")
            tensors[name] = np.array(a, dtype="<f4", order="C")  # (ascontiguousarray turns 0-d into 1-d)
        data = safetensors.numpy.save(tensors, metadata=meta)
        if len(data) > self.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {self.MAX_BYTES}")
        return data

    def _metadata(self) -> dict[str, str]:
        _check_meta_str("run", self.run, _NAME_RE)
        _check_meta_str("incarnation", self.incarnation, _TOKEN_RE)
        _check_count("version", self.version)
        if self.revision is not None:
            _check_count("revision", self.revision)
        if isinstance(self.t_published, bool) or not isinstance(self.t_published, (int, float, np.floating)):
            raise ProtocolError("wrong_type", "t_published: expected number")
        t = float(self.t_published)
        if not math.isfinite(t):
            raise ProtocolError("non_finite", "t_published")
        if t < 0:
            raise ProtocolError("bad_value", f"t_published: {t}")
        meta = {
            "format": FORMAT_TAG,
            "protocol": str(PROTOCOL_VERSION),
            "run": self.run,
            "incarnation": self.incarnation,
            "version": str(int(self.version)),
            "t_published": repr(t),
        }
        if self.revision is not None:
            meta["revision"] = str(int(self.revision))
        return meta

    def validate(self) -> None:
        self.encode()

    # -- decode -------------------------------------------------------------------------------------------
    @classmethod
    def decode(cls, data: bytes, expected: Spec | None = None) -> Weights:
        """Parse and validate. ``expected`` maps every tensor name to its shape; when given, the names must
        match exactly and every shape must equal, else ``bad_shape``."""
        import safetensors.numpy

        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ProtocolError("malformed", f"expected bytes, got {type(data).__name__}")
        data = bytes(data)
        if len(data) > cls.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > limit {cls.MAX_BYTES}")
        if len(data) < 8:
            raise ProtocolError("malformed", "shorter than a safetensors header")
        (n,) = struct.unpack("<Q", data[:8])
        if n > MAX_HEADER or 8 + n > len(data):
            raise ProtocolError("malformed", f"header length {n} out of bounds")
        header = parse_json(data[8 : 8 + n], MAX_HEADER)
        if not isinstance(header, dict):
            raise ProtocolError("malformed", "header is not a JSON object")
        meta = header.pop("__metadata__", None)
        if not isinstance(meta, dict):
            raise ProtocolError("missing_field", "__metadata__")
        for key in METADATA_FIELDS:
            if key not in meta:
                raise ProtocolError("missing_field", f"__metadata__.{key}")
        extra = [k for k in meta if k not in METADATA_FIELDS and k not in OPTIONAL_METADATA_FIELDS]
        if extra:
            raise ProtocolError("extra_field", f"__metadata__.{str(extra[0])[:40]}")
        for k, v in meta.items():
            if not isinstance(v, str):
                raise ProtocolError("wrong_type", f"__metadata__.{k}: expected string")
        if meta["format"] != FORMAT_TAG:
            raise ProtocolError("bad_value", f"format: {meta['format'][:40]!r}")
        if meta["protocol"] != str(PROTOCOL_VERSION):
            raise ProtocolError("bad_value", f"protocol: {meta['protocol'][:40]!r}")
        _check_meta_str("run", meta["run"], _NAME_RE)
        _check_meta_str("incarnation", meta["incarnation"], _TOKEN_RE)
        version = _parse_int(meta["version"], "version")
        t_published = _parse_float(meta["t_published"], "t_published")
        revision = _parse_int(meta["revision"], "revision") if "revision" in meta else None
        if len(header) > MAX_TENSORS:
            raise ProtocolError("bad_value", f"more than {MAX_TENSORS} tensors")
        for name, info in header.items():
            _check_tensor_name(name)
            if not isinstance(info, dict) or info.get("dtype") != "F32":
                dtype = info.get("dtype") if isinstance(info, dict) else info
                raise ProtocolError("bad_shape", f"{name}: dtype {dtype!r}, expected F32")
            shape = info.get("shape")
            if not isinstance(shape, list) or len(shape) > MAX_NDIM:
                raise ProtocolError("bad_shape", f"{name}: bad shape {shape!r}")
        try:
            arrays = safetensors.numpy.load(data)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # SafetensorError, or a Rust panic (a BaseException): any bad file
            raise ProtocolError("malformed", f"safetensors: {str(e)[:80]}") from None
        tensors: dict[str, np.ndarray] = {}
        for name in header:
            a = arrays[name]
            if a.dtype != np.float32:
                raise ProtocolError("bad_shape", f"{name}: dtype {a.dtype}")
            if not np.isfinite(a).all():
                raise ProtocolError("non_finite", f"{name}: contains NaN or Inf")
            tensors[name] = a
        if expected is not None:
            check_spec(tensors, expected)
        return cls(
            run=meta["run"],
            incarnation=meta["incarnation"],
            version=version,
            t_published=t_published,
            tensors=tensors,
            revision=revision,
        )

    # -- helpers ------------------------------------------------------------------------------------------
    @property
    def progress(self) -> tuple[int, int]:
        """(version, revision), increasing with each publication of one learner incarnation: a receiver takes
        weights only when this is greater than what it holds (no revision, as in older logs: -1). The version
        first: it is bounded by the steps the actor sent, the revision is not."""
        return (int(self.version), -1 if self.revision is None else int(self.revision))

    def spec(self) -> dict[str, tuple[int, ...]]:
        """Names and shapes, in the form ``decode(expected=...)`` takes."""
        return {k: tuple(np.shape(v)) for k, v in self.tensors.items()}

    def same_as(self, other: Weights) -> bool:
        return (
            (self.run, self.incarnation, self.version, self.revision, self.t_published)
            == (other.run, other.incarnation, other.version, other.revision, other.t_published)
            and self.tensors.keys() == other.tensors.keys()
            and all(np.array_equal(np.asarray(self.tensors[k]), np.asarray(other.tensors[k])) for k in self.tensors)
        )

    @classmethod
    def json_schema(cls) -> dict:
        """A JSON Schema (draft 2020-12) of the safetensors *header* (the JSON after the 8-byte length)."""
        meta_props = {
            k: {"type": "string", "description": d} for k, d in {**METADATA_FIELDS, **OPTIONAL_METADATA_FIELDS}.items()
        }
        meta_props["format"]["const"] = FORMAT_TAG
        meta_props["protocol"]["const"] = str(PROTOCOL_VERSION)
        meta_props["version"]["pattern"] = meta_props["revision"]["pattern"] = f"^{VERSION_PATTERN}$"
        return {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "$id": f"urn:hitl-tamer:protocol:{PROTOCOL_VERSION}:{cls.TYPE_NAME}",
            "title": cls.TYPE_NAME,
            "description": (
                "Binary message in the safetensors format: u64 little-endian header length N, N bytes "
                "of UTF-8 JSON header (described by this schema), then the raw little-endian float32 "
                "tensor data. Never pickle."
            ),
            "x-message-encoding": "safetensors",
            "type": "object",
            "properties": {
                "__metadata__": {
                    "type": "object",
                    "properties": meta_props,
                    "required": list(METADATA_FIELDS),
                    "additionalProperties": False,
                }
            },
            "required": ["__metadata__"],
            "propertyNames": {"pattern": "^(__metadata__|[A-Za-z0-9_.]{1,128})$"},
            "maxProperties": MAX_TENSORS + 1,
            "additionalProperties": {
                "type": "object",
                "properties": {
                    "dtype": {"const": "F32"},
                    "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}, "maxItems": MAX_NDIM},
                    "data_offsets": {
                        "type": "array",
                        "items": {"type": "integer", "minimum": 0},
                        "minItems": 2,
                        "maxItems": 2,
                    },
                },
                "required": ["dtype", "shape", "data_offsets"],
                "additionalProperties": False,
            },
        }


def check_spec(tensors: Mapping[str, Any], expected: Spec) -> None:
    """Raise ``bad_shape`` unless ``tensors`` has exactly the names of ``expected``, with those shapes."""
    if set(tensors) != set(expected):
        missing = sorted(set(expected) - set(tensors))
        extra = sorted(set(tensors) - set(expected))
        raise ProtocolError("bad_shape", f"tensor names differ: missing {missing[:4]}, unexpected {extra[:4]}")
    for name, shape in expected.items():
        got = tuple(np.shape(tensors[name]))
        if got != tuple(shape):
            raise ProtocolError("bad_shape", f"{name}: shape {got}, expected {tuple(shape)}")


def _check_tensor_name(name: Any) -> None:
    if not isinstance(name, str):
        raise ProtocolError("wrong_type", "tensor name is not a string")
    if not _TENSOR_NAME_RE.match(name):
        raise ProtocolError("bad_value", f"tensor name {name[:40]!r} does not match {TENSOR_NAME_PATTERN}")


def _check_count(key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ProtocolError("wrong_type", f"{key}: expected integer")
    if not 0 <= int(value) <= SAFE_INT:
        raise ProtocolError("bad_value", f"{key}: {value}")


def _check_meta_str(key: str, value: Any, pattern: re.Pattern) -> None:
    if not isinstance(value, str):
        raise ProtocolError("wrong_type", f"{key}: expected string")
    if not pattern.match(value):
        raise ProtocolError("bad_value", f"{key}: {value[:40]!r}")


def decimal_at_most(n: int) -> str:
    """A regular expression of the decimal integers 0..n (no leading zeros): the schema states the bound the
    decoder checks, so both accept exactly the same strings."""
    d = str(n)
    k = len(d)
    if k == 1:
        return f"[0-{n}]"
    alts = ["[0-9]"] + ([f"[1-9][0-9]{{1,{k - 2}}}"] if k > 2 else [])  # every shorter number
    for i in range(k):  # same length: equal up to digit i, smaller there, anything after
        low, top = (1 if i == 0 else 0), int(d[i]) - 1
        if top >= low:
            rest = k - i - 1
            alts.append(d[:i] + f"[{low}-{top}]" + (f"[0-9]{{{rest}}}" if rest else ""))
    alts.append(d)
    return "(" + "|".join(alts) + ")"


VERSION_PATTERN = decimal_at_most(SAFE_INT)
_VERSION_RE = re.compile(VERSION_PATTERN + r"\Z")


def _parse_int(s: str, key: str) -> int:
    if not _VERSION_RE.match(s):
        raise ProtocolError("bad_value", f"{key}: {s[:40]!r} is not a decimal integer in [0, 2^53-1]")
    return int(s)


def _parse_float(s: str, key: str) -> float:
    if not _FLOAT_RE.fullmatch(s):
        raise ProtocolError("bad_value", f"{key}: {s[:40]!r} is not a non-negative decimal number")
    v = float(s)
    if not math.isfinite(v):
        raise ProtocolError("non_finite", key)
    if v < 0:
        raise ProtocolError("bad_value", f"{key}: {v}")
    return v


def header_json(data: bytes) -> dict:
    """The safetensors header of an encoded Weights message (for tools and tests)."""
    (n,) = struct.unpack("<Q", data[:8])
    return json.loads(data[8 : 8 + n])
