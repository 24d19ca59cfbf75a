"""The reproduction's per-trial data as one tidy table: one row per (condition, arm, trial, episode).

`docs/results/trials.csv.xz` is committed beside REPORT.md, so anyone can recompute every verdict,
interval and figure without running a trial: `python -m experiments report --from
docs/results/trials.csv.xz --out DIR`. `reproduce` writes the table and then analyses the table it wrote
(`read_table`), so the committed report and a recomputation read the same numbers.

Columns (COLUMNS): condition, arm, trial (k: the same layout and seed under every arm of a condition's
layout set), layout (maze layout; Taxi: fixed task or 0), layout_class (honest | misleading | taxi), seed,
cluster (the resampling unit: the layout; Gymnasium's Taxi: the seed), episode (from 1), steps, return,
then the per-episode extras of the runner: alpha_h at the episode's end, feedback given and credited, the
greedy actions and those H decided against Q, the mean of the lag distribution credit used. A field an arm
does not have is empty. Floats are written with Python's shortest round-trip repr: reading gives the
same bits. xz's stream carries no time stamp, so the same trials give the same file.
"""

from __future__ import annotations

import csv
import gzip
import lzma
import io
from dataclasses import dataclass

import numpy as np

from common.envs.maze import layout_kind
from experiments.conditions import BY_NAME, Condition, Scale, cluster_of, n_trials
from experiments.evaluate import ArmData
from experiments.trialcache import EXTRA_FIELDS

KEYS = ("condition", "arm", "trial", "layout", "layout_class", "seed", "cluster", "episode", "steps", "return")
COLUMNS = KEYS + EXTRA_FIELDS
TABLE = "trials.csv.xz"
"""The table's file name in a results directory."""
INT_FIELDS = ("feedback_given", "feedback_credited", "h_decided", "greedy")


@dataclass
class Table:
    """What the analysis needs, read back from the table: condition -> arm -> ArmData and extras."""

    conditions: list[Condition]
    data: dict[str, dict[str, ArmData]]
    extras: dict[str, dict[str, dict[str, np.ndarray]]]
    seeds: dict[str, np.ndarray]


def layout_class(cond: Condition, layout: int) -> str:
    return "taxi" if cond.is_taxi else layout_kind(int(layout))


def _cell(field: str, value) -> str:
    if field in INT_FIELDS:
        return str(int(value))
    return repr(float(value))


def table_rows(conds: list[Condition], scale: Scale, records: dict) -> list[list[str]]:
    """Rows of every (condition, arm, trial, episode); `records[(cond, arm, k)]` as the trial cache holds."""
    rows = []
    for c in conds:
        for arm in c.arms:
            for k in range(n_trials(c, scale)):
                r = records[(c.name, arm, k)]
                layout, seed = int(r["spec"]["layout"]), int(r["spec"]["seed"])
                head = [
                    c.name,
                    arm,
                    str(k),
                    str(layout),
                    layout_class(c, layout),
                    str(seed),
                    str(cluster_of(c, scale, k)),
                ]
                extras = [r.get(f) for f in EXTRA_FIELDS]
                for e in range(len(r["steps"])):
                    rows.append(
                        head
                        + [str(e + 1), str(int(r["steps"][e])), repr(float(r["return"][e]))]
                        + ["" if x is None else _cell(f, x[e]) for f, x in zip(EXTRA_FIELDS, extras)]
                    )
    return rows


def write_table(path: str, conds: list[Condition], scale: Scale, records: dict) -> int:
    """Write the table (xz: under the repository's 2 MB per file where gzip was not); returns its number of rows."""
    rows = table_rows(conds, scale, records)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    writer.writerows(rows)
    with lzma.open(path, "wb", preset=9) as fh:
        fh.write(text.getvalue().encode())
    return len(rows)


def _arrays(rows: list[dict], field: str, n: int, E: int, dtype=np.float64) -> np.ndarray:
    out = np.empty((n, E), dtype)
    for r in rows:
        out[int(r["trial"]), int(r["episode"]) - 1] = float(r[field])
    return out


def read_table(path: str) -> Table:
    """The table at `path` as the analysis's arrays; the conditions come from their names (declared in
    experiments/conditions.py). A malformed table is a ValueError naming what is wrong."""
    opener = gzip.open if str(path).endswith(".gz") else lzma.open  # (tables written before 26 November: gzip)
    with opener(path, "rt", newline="") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in KEYS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: not a trials table (missing columns {', '.join(missing)})")
        groups: dict[tuple[str, str], list[dict]] = {}
        for r in reader:
            groups.setdefault((r["condition"], r["arm"]), []).append(r)
    unknown = sorted({cond for cond, _ in groups if cond not in BY_NAME})
    if unknown:
        raise ValueError(f"{path}: unknown conditions {', '.join(unknown)}")
    names = list(dict.fromkeys(cond for cond, _ in groups))
    conds = [BY_NAME[n] for n in names]
    data: dict = {n: {} for n in names}
    extras: dict = {n: {} for n in names}
    seeds: dict = {}
    for (name, arm), rows in groups.items():
        c = BY_NAME[name]
        n = 1 + max(int(r["trial"]) for r in rows)
        E = max(int(r["episode"]) for r in rows)
        if len(rows) != n * E:
            raise ValueError(f"{path}: {name}/{arm} has {len(rows)} rows, not {n} trials x {E} episodes")
        first = {int(r["trial"]): r for r in rows if r["episode"] == "1"}
        per_trial = [first[k] for k in range(n)]
        data[name][arm] = ArmData(
            _arrays(rows, "steps", n, E),
            _arrays(rows, "return", n, E),
            np.array([int(r["layout"]) for r in per_trial]),
            np.array([int(r["cluster"]) for r in per_trial]),
            c.stop_episode,
            c.is_taxi,
        )
        extras[name][arm] = {
            f: _arrays(rows, f, n, E) for f in EXTRA_FIELDS if f in rows[0] and all(r[f] != "" for r in rows)
        }
        seeds[f"{name}/{arm}"] = np.array([int(r["seed"]) for r in per_trial])
    # A condition's arms in their declared order (the figures' and the panels' order).
    for name in names:
        strange = [a for a in data[name] if a not in BY_NAME[name].arms]
        if strange:
            raise ValueError(f"{path}: {name} declares no arm {', '.join(strange)}")
        order = [a for a in BY_NAME[name].arms if a in data[name]]
        data[name] = {a: data[name][a] for a in order}
        extras[name] = {a: extras[name][a] for a in order}
    return Table(conds, data, extras, seeds)
