"""A sweep's tables and figures: the tidy table (CSV and Parquet), the per-cell summary, one figure per group.

Tidy table: one row per (cell, trial, episode); columns: `cell`, every swept field (named by its path,
e.g. `observer.p_feedback`), `trial`, `layout`, `seed`, `episode` (from 0), `return`, `steps`,
`feedback_given`, `feedback_credited` (empty for agents that ignore feedback: their trials are shared by
cells that differ only in the observer, so the observer's counts would depend on which cell ran first).
Tuple values (delay distributions) are written as text
('[0.3,0.6,0.1]') so that every column has one type.
"""
from __future__ import annotations

import csv
import os

import numpy as np

from experiments import curvestats as claims
from experiments.sweeps.analysis import group_title, groups, legend_field, stop_of
from experiments.sweeps.grid import Sweep, fmt_value

EPISODE_COLUMNS = ("return", "steps", "feedback_given", "feedback_credited")
SUMMARY_METRICS = ("auc", "final", "initial", "post_stop", "to90")


def _column_value(v):
    return fmt_value(v) if isinstance(v, tuple) or v is None else v


def tidy_columns(sweep: Sweep) -> dict[str, list]:
    """The tidy table as columns (name -> values), rows ordered by cell, trial, episode."""
    cols: dict[str, list] = {"cell": []}
    for p in sweep.grid:
        cols[p] = []
    for name in ("trial", "layout", "seed", "episode", *EPISODE_COLUMNS):
        cols[name] = []
    return cols


def tidy_table(sweep: Sweep, records: dict[tuple[int, int], dict]) -> dict[str, list]:
    cols = tidy_columns(sweep)
    for cell in sweep.cells():
        for k in range(sweep.trials):
            rec = records[(cell.index, k)]
            n = len(rec["return"])
            layout, seed = rec["spec"]["layout"], rec["spec"]["seed"]
            cols["cell"] += [cell.label] * n
            for p, v in cell.values.items():
                cols[p] += [_column_value(v)] * n
            cols["trial"] += [k] * n
            cols["layout"] += [layout] * n
            cols["seed"] += [seed] * n
            cols["episode"] += list(range(n))
            agent = rec["spec"]["agent"]
            uses_feedback = agent["train_h"] or agent["reward_shaping"]
            for name in EPISODE_COLUMNS:
                ignored = name.startswith("feedback") and not uses_feedback
                cols[name] += [None] * n if ignored else list(rec[name])
    return cols


def write_tidy(cols: dict[str, list], out: str) -> tuple[str, str]:
    """trials.csv and trials.parquet in `out`."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    csv_path, pq_path = os.path.join(out, "trials.csv"), os.path.join(out, "trials.parquet")
    names = list(cols)
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        w.writerows(zip(*(cols[c] for c in names)))
    pq.write_table(pa.table(cols), pq_path)
    return csv_path, pq_path


def write_summary(summary: dict, sweep: Sweep, out: str) -> str:
    """summary.csv: one row per cell, each metric's estimate and 95% interval."""
    path = os.path.join(out, "summary.csv")
    head = ["cell", *sweep.grid, "trials", "episodes"]
    for m in SUMMARY_METRICS:
        head += [m, f"{m}_lo", f"{m}_hi"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head)
        for row in summary.values():
            line = [row["cell"], *(_column_value(row["values"][p]) for p in sweep.grid), row["trials"],
                    row["episodes"]]
            for m in SUMMARY_METRICS:
                iv = row.get(m)
                line += [iv["estimate"], iv["ci"][0], iv["ci"][1]] if iv else ["", "", ""]
            w.writerow(line)
    return path


def plot_groups(sweep: Sweep, returns: dict[int, np.ndarray], out: str) -> list[str]:
    """One figure per group: a trimmed-mean curve with its bootstrap band per legend value."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    leg = legend_field(sweep)
    paths = []
    for g, (fixed, cells) in enumerate(groups(sweep)):
        fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=100)
        for cell in cells:
            mid, lo, hi = claims.curve_band(returns[cell.index])
            x = np.arange(1, len(mid) + 1)
            label = f"{leg}={fmt_value(cell.values[leg])}" if leg else cell.label
            (line,) = ax.plot(x, mid, lw=1.5, label=label)
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.15, lw=0)
        stops = {stop_of(sweep, c) for c in cells} - {None}
        for s in stops:
            ax.axvline(s + 0.5, color="black", ls="--", lw=1)
        env = sweep.spec(cells[0], 0).env
        ax.set_title(f"{sweep.name}: {group_title(fixed)}\n{env}, 10%-trimmed mean of {sweep.trials} trials, "
                     "95% bootstrap band", fontsize=9)
        ax.set_xlabel("episode")
        ax.set_ylabel("return per episode")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right", title=None)
        fig.tight_layout()
        path = os.path.join(out, f"group-{g:02d}.png")
        fig.savefig(path)
        plt.close(fig)
        paths.append(path)
    return paths
