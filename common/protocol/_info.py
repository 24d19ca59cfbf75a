"""Step.info from an environment's `info`: the whole mapping, or an error naming the key that cannot be sent."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ._messages import MAX_INFO_ITEMS, MAX_INFO_KEY


class InfoError(ValueError):
    """An environment's `info` that a Step cannot carry; the message names the key."""


def _number(key: str, value: Any) -> float:
    if isinstance(value, (str, bytes)) or value is None:
        raise InfoError(
            f"env info key {key!r}: {type(value).__name__} {value!r:.60} is not a number (a Step carries numbers only)"
        )
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InfoError(
            f"env info key {key!r}: {type(value).__name__} {value!r:.60} is not a number (a Step carries numbers only)"
        ) from None
    if not math.isfinite(number):
        raise InfoError(f"env info key {key!r}: {number} is not a finite number (a Step carries finite numbers only)")
    return number


def step_info(info: Mapping[str, Any]) -> dict[str, float]:
    """The environment's `info` as Step.info carries it: every key, each a finite number (a bool is 0/1).

    Raises InfoError naming the first key that cannot be sent (not 1..`MAX_INFO_KEY` printable characters, not
    a finite number) or the keys past `MAX_INFO_ITEMS`: a teacher rule sees what the env said, never a silently
    shortened copy."""
    if not isinstance(info, Mapping):
        raise InfoError(f"env info must be a mapping of names to numbers, got {type(info).__name__}")
    out: dict[str, float] = {}
    for key, value in info.items():
        if not isinstance(key, str) or not 1 <= len(key) <= MAX_INFO_KEY or not key.isprintable():
            raise InfoError(f"env info key {key!r:.80}: a Step carries keys of 1..{MAX_INFO_KEY} printable characters")
        out[key] = _number(key, value)
    if len(out) > MAX_INFO_ITEMS:
        extra = ", ".join(repr(k) for k in list(out)[MAX_INFO_ITEMS:])
        raise InfoError(
            f"env info has {len(out)} keys, a Step carries at most {MAX_INFO_ITEMS}: {extra} cannot be sent"
        )
    return out
