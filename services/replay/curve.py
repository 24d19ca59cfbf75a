"""The learning curve of a run's summary as a PNG, when matplotlib (the `experiments` extra) is installed."""

from __future__ import annotations

import os
import sys
from typing import Any

import numpy as np


def plot_summary(s: dict[str, Any], path: str | os.PathLike, title: str | None = None) -> bool:
    """Draw the learning curve into `path`; without matplotlib, say so in one line on stderr and return False."""
    try:
        from common.logs.plots import plot_curves, pyplot

        pyplot()  # (matplotlib is imported when a figure is first drawn: whether it is installed shows here)
    except ImportError as exc:
        print(
            f"no {os.path.basename(path)}: {exc.name} is not installed (pip install 'hitl-tamer[experiments]')",
            file=sys.stderr,
        )
        return False
    rets = np.asarray(s["returns"], dtype=float)
    plot_curves({"live": rets}, str(path), title or f"live run {s['run']}: return per episode")
    return True
