"""Independent random streams derived from one trial seed, one per purpose.

Separate streams keep parts from disturbing each other: training H does not change which exploratory
actions a trial takes, so DQN-TAMER with alpha_h = 0 acts exactly as DQN.
"""

from __future__ import annotations

import zlib

import numpy as np


def derive_seed(seed: int, purpose: str) -> int:
    return int(np.random.SeedSequence([int(seed), zlib.crc32(purpose.encode())]).generate_state(1, np.uint64)[0])


def stream(seed: int, purpose: str) -> np.random.Generator:
    return np.random.default_rng(derive_seed(seed, purpose))
