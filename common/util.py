"""Small numpy helpers shared by the core."""
from __future__ import annotations

import numpy as np


def nz(mask: np.ndarray) -> np.ndarray:
    """Indices of the true entries of a 1-d mask (np.flatnonzero without its overhead)."""
    return mask.nonzero()[0]
