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


def to_integers(u: np.ndarray, high: np.ndarray) -> np.ndarray:
    """floor(u * high) for uniforms u in [0, 1), kept below high."""
    out = np.floor(u * np.asarray(high, dtype=np.float64)).astype(np.int64)
    return np.minimum(out, np.asarray(high, dtype=np.int64) - 1)


class UniformBlocks:
    """u(key_i, c * width + j) for j < width, served from blocks of `block` consecutive counters c per
    row, computed in one vectorised call when a row's counter leaves its block. The values are exactly
    `uniforms`' (so results do not change); only the number of calls does. Rows can be dropped with
    `select`, like the rest of a batch's state; nothing needs saving (the blocks are recomputed)."""

    def __init__(self, keys: np.ndarray, width: int, block: int | None = None):
        self.keys = np.asarray(keys, dtype=np.uint64)
        self.width = width
        self.block = block if block is not None else max(8, 2048 // width)
        self.base = np.full(len(self.keys), -1 << 62, dtype=np.int64)
        self.values = np.zeros((len(self.keys), self.block, width), np.float64)

    def get(self, rows: np.ndarray, counters: np.ndarray) -> np.ndarray:
        """[len(rows), width] for counter counters[k] of row rows[k] (rows distinct)."""
        off = counters - self.base[rows]
        stale = (off < 0) | (off >= self.block)
        if np.count_nonzero(stale):  # (a C call: a quarter of .any()'s cost, per step)
            r = rows[stale]
            c0 = counters[stale]
            c = (c0[:, None, None] + np.arange(self.block)[None, :, None]) * self.width + np.arange(self.width)
            self.values[r] = uniforms(self.keys[r, None, None], c)
            self.base[r] = c0
            off = counters - self.base[rows]
        return self.values[rows, off]

    def select(self, rows: np.ndarray) -> None:
        self.keys, self.base, self.values = self.keys[rows], self.base[rows], self.values[rows]
