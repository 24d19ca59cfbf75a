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

from experiments import stats
from experiments.sweeps.analysis import METRICS, CellData, group_title, groups, legend_field, stop_of
from experiments.sweeps.grid import Sweep, fmt_value

EPISODE_COLUMNS = ("return", "steps", "feedback_given", "feedback_credited")
SUMMARY_METRICS = METRICS


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
    head = ["cell", *sweep.grid, "trials", "clusters", "episodes"]
    for m in SUMMARY_METRICS:
        head += [m, f"{m}_lo", f"{m}_hi"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head)
        for row in summary.values():
            line = [
                row["cell"],
                *(_column_value(row["values"][p]) for p in sweep.grid),
                row["trials"],
                row["clusters"],
                row["episodes"],
            ]
            for m in SUMMARY_METRICS:
                iv = row.get(m)
                line += [iv["estimate"], iv["ci"][0], iv["ci"][1]] if iv else ["", "", ""]
            w.writerow(line)
    return path


def plot_groups(sweep: Sweep, data: dict[int, CellData], out: str) -> list[str]:
    """One figure per group, one line per legend value: steps per episode (geometric mean over trials, as
    the reproduction's figures) and mean return per episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    leg = legend_field(sweep)
    paths = []
    for g, (fixed, cells) in enumerate(groups(sweep)):
        fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(9.6, 3.9), dpi=90)
        for cell in cells:
            d = data[cell.index]
            label = f"{leg}={fmt_value(cell.values[leg])}" if leg else cell.label
            x = np.arange(1, d.steps.shape[1] + 1)
            (line,) = ax_s.plot(x, np.exp(stats.log_steps(d.steps).mean(axis=0)), lw=1.4, label=label)
            ax_r.plot(x, d.returns.mean(axis=0), lw=1.4, color=line.get_color(), label=label)
        for ax in (ax_s, ax_r):
            for s in {stop_of(sweep, c) for c in cells} - {None}:
                ax.axvline(s + 0.5, color="black", ls="--", lw=0.8)
            ax.set_xlabel("episode")
            ax.grid(alpha=0.3, which="both")
        ax_s.set_yscale("log")
        ax_s.set_ylabel("steps per episode (geometric mean)")
        ax_r.set_ylabel("return per episode (mean)")
        ax_s.legend(fontsize=8, loc="upper right")
        env = sweep.spec(cells[0], 0).env
        fig.suptitle(f"{sweep.name}: {group_title(fixed)} ({env}, {sweep.trials} trials per line)", fontsize=10)
        fig.tight_layout()
        path = os.path.join(out, f"group-{g:02d}.png")
        fig.savefig(path)
        plt.close(fig)
        paths.append(path)
    return paths
