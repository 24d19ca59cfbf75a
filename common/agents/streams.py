"""Counter-based random numbers: a uniform draw is a pure function of (key, counter).

The agent's random choices (exploration, replay sampling) are indexed by what they are for: trial key,
step or update number, draw number. A draw therefore does not depend on any other trial, on the order in
which trials are visited, nor on hidden generator state, so a batch of trials can draw for all of them in
one vectorised call, a batch can be shrunk or reordered between steps, and a restarted learner continues
the same sequence from its counters alone (nothing to save but the counters).

The mixing function is SplitMix64's finaliser (Steele, Lea and Flood 2014) applied to
key + counter * golden-gamma; the 53 high bits give a double in [0, 1).
"""
from __future__ import annotations

import numpy as np

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TO_UNIT = 1.0 / float(1 << 53)


def mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def uniforms(keys: np.ndarray, counters: np.ndarray) -> np.ndarray:
    """Doubles in [0, 1): u[k] = f(keys[k], counters[k]) (the arrays broadcast together)."""
    with np.errstate(over="ignore"):
        k = np.asarray(keys, dtype=np.uint64)
        c = np.asarray(counters, dtype=np.int64).astype(np.uint64)
        z = mix64(k + c * _GAMMA)
    return (z >> _S11).astype(np.float64) * _TO_UNIT


def integers(keys: np.ndarray, counters: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Integers in [0, high) from `uniforms` (floor(u * high); bias below 2^-40 for high < 2^13)."""
    u = uniforms(keys, counters)
    out = np.floor(u * np.asarray(high, dtype=np.float64)).astype(np.int64)
    return np.minimum(out, np.asarray(high, dtype=np.int64) - 1)
