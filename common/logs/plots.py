"""Learning-curve plots (matplotlib, headless)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def pyplot():
    """pyplot on the file backend, imported when a figure is drawn, not with this module: it takes about a
    second, and every `python -m experiments` command imports a module that plots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_curves(
    curves: dict[str, np.ndarray],
    path: str,
    title: str,
    ylabel: str = "return per episode",
    stop_episode: int | None = None,
    bands: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
):
    """One line per name (x = episode); optional shaded bands; a dashed line where feedback stops."""
    fig, ax = pyplot().subplots(figsize=(6, 4), dpi=110)
    for name, y in curves.items():
        x = np.arange(len(y))
        (line,) = ax.plot(x, y, label=name, lw=1.6)
        if bands and name in bands:
            lo, hi = bands[name]
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.18, lw=0)
    if stop_episode is not None:
        ax.axvline(stop_episode, color="grey", ls="--", lw=1)
        ax.text(stop_episode, ax.get_ylim()[1], " feedback stops", va="top", fontsize=8, color="grey")
    ax.set_xlabel("episode")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_whole(fig, path)


def save_whole(fig, path) -> None:
    """Save to a temporary file beside `path`, then rename: a full disk leaves no 0-byte or partial image."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        pyplot().close(fig)
