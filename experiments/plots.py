"""Learning-curve plots: the helper lives in `common.plots` (the live services use it too)."""
from common.plots import plot_curves

__all__ = ["plot_curves"]
