"""Learning-curve plots: the helper lives in `common.logs.plots` (the live services use it too)."""

from common.logs.plots import plot_curves

__all__ = ["plot_curves"]
