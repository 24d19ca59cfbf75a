"""A sweep's numbers: per-cell summaries (the reproduction's metrics and intervals) and named contrasts.

Groups: the cells that differ only in the legend field (by default `agent.algo` when it is swept, else
the last swept field) form a group, as the four agents of one condition do in the reproduction. Each
cell's table is `claims.condition_table` with its group's start and best levels, so the numbers mean
what the reproduction's do (AUC, final, initial, post-stop gain when feedback stops, episodes to 90%).

Contrasts: `"agent.algo=dqn-tamer - agent.algo=dqn"` (optionally prefixed `final:` or another metric)
compares, within every combination of the fields it does not name, the cell matching the left side with
the cell matching the right, paired by trial. Verdicts: `A > B` when the interval is above 0, `A < B`
when below, `no meaningful difference` when it lies within +-NEGLIGIBLE of the group's return scale,
`inconclusive` otherwise. Each also gets its minimum detectable effect at this number of trials (80%
power, two-sided 5%) and the trials an effect of the size seen would need; a verdict resting on fewer
trials than that is flagged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from experiments import curvestats as claims
from experiments.sweeps.grid import Cell, Sweep, fmt_value, parse_assignment, parse_values

Z_ALPHA, Z_POWER = 1.959964, 0.841621  # two-sided 5%, 80% power
CONTRAST_METRICS = ("auc", "final", "initial", "post_stop")


# ----------------------------------------------------------------------- statistics adapter
def resample_index(clusters: np.ndarray, n_boot: int) -> np.ndarray:
    """[n_boot + 1, n] trial indices, row 0 the sample itself. The seam to the reproduction's
    statistics: `claims.boot_indices` resamples trials (paired: the same rows for every cell)."""
    return claims.boot_indices(len(clusters), n_boot)


def metric_values(name: str, R: np.ndarray, stop: int | None) -> np.ndarray:
    f = claims.post_stop if name == "post_stop" else claims.METRICS[name]
    return f(R, stop)


# ------------------------------------------------------------------------------------ groups
def legend_field(sweep: Sweep) -> str | None:
    if sweep.legend:
        return sweep.legend
    if "agent.algo" in sweep.grid:
        return "agent.algo"
    return list(sweep.grid)[-1] if sweep.grid else None


def groups(sweep: Sweep) -> list[tuple[dict, list[Cell]]]:
    """(values of the non-legend fields, cells) for every group, in grid order."""
    leg = legend_field(sweep)
    out: dict[str, tuple[dict, list[Cell]]] = {}
    for cell in sweep.cells():
        fixed = {p: v for p, v in cell.values.items() if p != leg}
        out.setdefault(repr(sorted((p, fmt_value(v)) for p, v in fixed.items())), (fixed, []))[1].append(cell)
    return list(out.values())


def group_title(fixed: dict) -> str:
    return ", ".join(f"{p}={fmt_value(v)}" for p, v in fixed.items()) or "all cells"


def stop_of(sweep: Sweep, cell: Cell) -> int | None:
    return sweep.spec(cell, 0).observer.stop_episode


def summarize(sweep: Sweep, returns: dict[int, np.ndarray], clusters: np.ndarray, n_boot: int) -> dict:
    """Per cell: the reproduction's metrics with intervals, under its group's levels."""
    idx = resample_index(clusters, n_boot)
    out = {}
    for fixed, cells in groups(sweep):
        lo, hi = claims.condition_levels({c.index: returns[c.index] for c in cells})
        for c in cells:
            cd = claims.CondData(c.label, {c.index: returns[c.index]}, stop_of(sweep, c), lo, hi)
            out[c.index] = {"cell": c.label, "values": c.values, "group": group_title(fixed),
                            "trials": int(returns[c.index].shape[0]), "episodes": int(returns[c.index].shape[1]),
                            "start_level": lo, "best_level": hi, "stop": cd.stop,
                            **claims.condition_table(cd, idx)[c.index]}
    return out


# --------------------------------------------------------------------------------- contrasts
@dataclass(frozen=True)
class Contrast:
    text: str
    metric: str
    left: dict
    right: dict


def parse_contrast(text: str, sweep: Sweep) -> Contrast:
    """'[metric:] F=V[,F=V] - F=V[,F=V]' with every field swept and every value in the grid."""
    metric, body = "auc", text.strip()
    head, sep, rest = body.partition(":")
    if sep and "=" not in head:
        metric, body = head.strip(), rest
    if metric not in CONTRAST_METRICS:
        raise ValueError(f"contrast {text!r}: unknown metric {metric!r} ({', '.join(CONTRAST_METRICS)})")
    sides = body.split(" - ")
    if len(sides) != 2:
        raise ValueError(f"contrast {text!r}: expected 'F=V - F=V' (a minus with spaces around it)")
    parsed = []
    for side in sides:
        values: dict = {}
        for part in _assignments(side):
            path, rhs = parse_assignment(part)
            if path not in sweep.grid:
                raise ValueError(f"contrast {text!r}: {path} is not swept")
            (v,) = parse_values(path, rhs)
            if v not in sweep.grid[path]:
                raise ValueError(f"contrast {text!r}: {path}={fmt_value(v)} is not in the grid")
            values[path] = v
        if not values:
            raise ValueError(f"contrast {text!r}: empty side")
        parsed.append(values)
    if set(parsed[0]) != set(parsed[1]) or parsed[0] == parsed[1]:
        raise ValueError(f"contrast {text!r}: both sides must set the same fields to different values")
    if metric == "post_stop" and any(stop_of(sweep, c) is None for c in sweep.cells()):
        raise ValueError(f"contrast {text!r}: post_stop needs observer.stop_episode in every cell")
    return Contrast(text.strip(), metric, parsed[0], parsed[1])


def _assignments(side: str) -> list[str]:
    from experiments.sweeps.grid import split_top
    parts = [p.strip() for p in split_top(side.strip())]
    # "a=1,2" is not a side; a comma starts a new assignment only before 'FIELD='.
    merged: list[str] = []
    for p in parts:
        if "=" in p or not merged:
            merged.append(p)
        else:
            merged[-1] += "," + p
    return [p for p in merged if p]


def _match(cell: Cell, want: dict) -> bool:
    return all(cell.values.get(p) == v for p, v in want.items())


def evaluate_contrast(con: Contrast, sweep: Sweep, returns: dict[int, np.ndarray], clusters: np.ndarray,
                      n_boot: int) -> list[dict]:
    """One row per combination of the fields the contrast does not name."""
    idx = resample_index(clusters, n_boot)
    n = len(clusters)
    named = set(con.left)
    rows = []
    by_rest: dict[str, list[Cell]] = {}
    for cell in sweep.cells():
        rest = {p: v for p, v in cell.values.items() if p not in named}
        by_rest.setdefault(repr(sorted((p, fmt_value(v)) for p, v in rest.items())), []).append(cell)
    for cells in by_rest.values():
        a = next(c for c in cells if _match(c, con.left))
        b = next(c for c in cells if _match(c, con.right))
        rest = {p: v for p, v in a.values.items() if p not in named}
        lo, hi = claims.condition_levels({c.index: returns[c.index] for c in cells})
        scale = max(hi - lo, 1e-9)
        ma = metric_values(con.metric, returns[a.index], stop_of(sweep, a))
        mb = metric_values(con.metric, returns[b.index], stop_of(sweep, b))
        diff = claims.tmean(ma[idx], axis=1) - claims.tmean(mb[idx], axis=1)
        iv = claims.interval(diff)
        margin = claims.NEGLIGIBLE * scale
        verdict = verdict_of(iv["ci"], margin)
        se = float(np.std(diff[1:], ddof=1))
        mde = (Z_ALPHA + Z_POWER) * se
        effect = margin if verdict == "no meaningful difference" else abs(iv["estimate"])
        needed = math.inf if effect <= 0 else max(2, math.ceil(n * (mde / effect) ** 2))
        rows.append({"contrast": con.text, "metric": con.metric, "where": group_title(rest),
                     "left": a.label, "right": b.label, **iv, "margin": margin, "verdict": verdict,
                     "trials": n, "mde": mde, "trials_needed": needed if math.isfinite(needed) else None,
                     "underpowered": bool(needed > n)})
    return rows


def verdict_of(ci: list[float], margin: float) -> str:
    lo, hi = ci
    if lo > 0:
        return "A > B"
    if hi < 0:
        return "A < B"
    if -margin < lo and hi < margin:
        return "no meaningful difference"
    return "inconclusive"


def warning_line(row: dict) -> str:
    need = "any number of" if row["trials_needed"] is None else f"about {row['trials_needed']}"
    return (f"warning: {row['contrast']} ({row['where']}): '{row['verdict']}' rests on {row['trials']} trials; "
            f"the minimum detectable effect there is {row['mde']:.3f}, and an effect of the size seen needs "
            f"{need} trials (80% power, 5% two-sided)")
