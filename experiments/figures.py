"""Figures of the reproduction: learning curves per layout subset, who decides (alpha_h, H vs Q), learned lags."""

from __future__ import annotations

import numpy as np

from common.logs.plots import pyplot
from experiments import stats
from experiments.claims import AGENT_NAMES
from experiments.evaluate import SUBSETS, ArmData, subset_mask

COLORS = {
    "dqn": "#1f77b4",
    "dqn-rs": "#ff7f0e",
    "deep-tamer": "#2ca02c",
    "dqn-tamer": "#d62728",
    "dqn-tamer/adaptive": "#9467bd",
    "dqn-tamer/matched": "#8c564b",
    "dqn-tamer/trusted": "#e377c2",
}
STYLES = {"uniform": ":", "true": "--", "learned": "-"}


def _style(arm: str) -> dict:
    algo, _, how = arm.partition("/")
    return {"color": COLORS.get(arm, COLORS.get(algo, "k")), "ls": STYLES.get(how, "-")}


def plot_condition(title: str, arms: dict[str, ArmData], stop: int | None, path: str) -> None:
    """Geometric-mean steps per episode (exp of the trials' mean ln steps), one panel per layout subset."""
    plt = pyplot()
    subsets = [
        s
        for s in SUBSETS
        if all(subset_mask(a, s) is not None for a in arms.values())
        and (s == "pooled" or not subset_mask(next(iter(arms.values())), s).all())
    ]
    fig, axes = plt.subplots(1, len(subsets), figsize=(4.6 * len(subsets), 3.8), dpi=90, squeeze=False)
    for ax, subset in zip(axes[0], subsets):
        for arm, a in arms.items():
            mask = subset_mask(a, subset)
            curve = np.exp(stats.log_steps(a.steps[mask]).mean(axis=0))
            ax.plot(np.arange(1, len(curve) + 1), curve, lw=1.4, label=AGENT_NAMES.get(arm, arm), **_style(arm))
        if stop is not None:
            ax.axvline(stop + 0.5, color="black", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_title(
            f"{subset} layouts ({int(subset_mask(next(iter(arms.values())), subset).sum())} trials)", fontsize=9
        )
        ax.set_xlabel("episode")
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("steps per episode (geometric mean)")
    axes[0][-1].legend(fontsize=7, loc="upper right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_who_decides(curves: dict[str, dict], path: str) -> None:
    """Top: alpha_h per episode; bottom: share of greedy actions H decided against Q. One column per
    condition, honest (solid) and misleading (dashed) layouts, one colour per arm."""
    plt = pyplot()
    names = list(curves)
    if not names:
        return
    fig, axes = plt.subplots(2, len(names), figsize=(3.6 * len(names), 5.6), dpi=90, squeeze=False)
    for j, cond in enumerate(names):
        for arm, by_subset in curves[cond].items():
            for subset, ls in (("honest", "-"), ("misleading", "--"), ("pooled", "-")):
                if subset not in by_subset or (subset == "pooled" and len(by_subset) > 1):
                    continue
                d = by_subset[subset]
                x = np.arange(1, len(d["alpha_h"]) + 1)
                kw = {"color": _style(arm)["color"], "ls": ls, "lw": 1.3}
                axes[0][j].plot(x, d["alpha_h"], label=f"{AGENT_NAMES.get(arm, arm)}, {subset}", **kw)
                axes[1][j].plot(x, d["h_decides"], **kw)
        axes[0][j].set_title(cond, fontsize=9)
        axes[1][j].set_xlabel("episode")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("alpha_h at episode end")
    axes[1][0].set_ylabel("share of greedy actions\nH decided against Q")
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_learned_lags(lags: dict[str, dict], path: str) -> None:
    """Mean lag of the learned distribution per episode (mean over trials) against the observer's true
    mean lag, per delay condition."""
    plt = pyplot()
    if not lags:
        return
    fig, axes = plt.subplots(1, len(lags), figsize=(3.6 * len(lags), 3.4), dpi=90, squeeze=False)
    for ax, (cond, d) in zip(axes[0], lags.items()):
        for arm, curve in d["learned"].items():
            ax.plot(np.arange(1, len(curve) + 1), curve, label=AGENT_NAMES.get(arm, arm), **_style(arm))
        ax.plot(np.arange(1, len(d["true"]) + 1), d["true"], color="black", ls="--", lw=1, label="true")
        ax.set_title(cond, fontsize=9)
        ax.set_xlabel("episode")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("mean lag (steps)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
