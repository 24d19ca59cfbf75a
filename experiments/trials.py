"""The reproduction's per-trial data as one tidy table: one row per (condition, arm, trial, episode).

`docs/results/trials.csv.xz` is committed beside REPORT.md (a table past PART_BYTES in pieces, read the same
way), so anyone can recompute every verdict, interval and figure without running a trial: `python -m experiments
report --from docs/results/trials.csv.xz --out DIR`. `reproduce` writes the table and then analyses the table it wrote
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
import os
from dataclasses import dataclass
from pathlib import Path

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


PART_BYTES = 1_900_000
"""A table whose xz stream would pass this is written as pieces `trials.csv.xz.part-001`, ... of at most this many
bytes each (the repository keeps files under 2 MB): the pieces joined in order are the one xz stream, so
`cat trials.csv.xz.part-* > trials.csv.xz` gives the whole file, and `read_table` reads either form."""


def table_parts(path: str | Path) -> list[Path]:
    """The pieces of a table written in parts, in order (none if it was written whole)."""
    p = Path(path)
    return sorted(p.parent.glob(f"{p.name}.part-*"))


def write_table(path: str, conds: list[Condition], scale: Scale, records: dict) -> int:
    """Write the table (xz, in pieces past PART_BYTES); returns its number of rows."""
    rows = table_rows(conds, scale, records)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(COLUMNS)
    writer.writerows(rows)
    stream = io.BytesIO()
    with lzma.open(stream, "wb", preset=9) as fh:
        fh.write(text.getvalue().encode())
    data = stream.getvalue()
    for stale in [Path(path), *table_parts(path)]:  # a run written again replaces both forms
        stale.unlink(missing_ok=True)
    if len(data) <= PART_BYTES:
        Path(path).write_bytes(data)
    else:
        for i, start in enumerate(range(0, len(data), PART_BYTES)):
            Path(f"{path}.part-{i + 1:03d}").write_bytes(data[start : start + PART_BYTES])
    return len(rows)


def table_bytes(path: str) -> bytes:
    """The table's compressed bytes, from the file or joined from its pieces (the same bytes either way)."""
    parts = table_parts(path)
    if not os.path.exists(path) and parts:
        return b"".join(p.read_bytes() for p in parts)
    return Path(path).read_bytes()


def _open_text(path: str):
    """The table's text, from the file or from its pieces."""
    if str(path).endswith(".gz"):  # tables written before 26 November
        return gzip.open(path, "rt", newline="")
    return lzma.open(io.BytesIO(table_bytes(path)), "rt", newline="")


def _arrays(rows: list[dict], field: str, n: int, E: int, dtype=np.float64) -> np.ndarray:
    out = np.empty((n, E), dtype)
    for r in rows:
        out[int(r["trial"]), int(r["episode"]) - 1] = float(r[field])
    return out


def read_table(path: str) -> Table:
    """The table at `path` as the analysis's arrays; the conditions come from their names (declared in
    experiments/conditions.py). A malformed table is a ValueError naming what is wrong."""
    with _open_text(path) as fh:
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
