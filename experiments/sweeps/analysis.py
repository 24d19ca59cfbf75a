"""A sweep's numbers: per-cell summaries and named contrasts, with the reproduction's metrics and statistics.

Per trial (as the reproduction's panels, `experiments/panels.py`): `ln_steps` (mean ln steps per episode,
the reproduction's primary metric, lower is better), `ln_steps_last10`, `success` (share of episodes that
reach the goal) and `return` (mean return per episode). Each cell's value is the mean over trials with a
95% layout-cluster bootstrap interval (`experiments.stats.cluster_bootstrap`: trials of one layout are
resampled together; environments without layouts resample trials).

Contrasts: `"agent.algo=dqn-tamer - agent.algo=dqn"` (optionally prefixed by a metric, `return: ...`)
compares, within every combination of the fields it does not name, the cell matching the left side with
the cell matching the right, paired by trial: the mean of the per-trial differences with its cluster
bootstrap interval, a two-sided t-test on the cluster means, Holm-adjusted over all the sweep's contrasts.
Verdicts: `A > B` / `A < B` (adjusted p < 0.05), `no meaningful difference` (interval inside +-margin: ln 1.1
for ln steps as in the claims, 0.05 for success, 2% of the group's return scale for return), else
`inconclusive`. Each also gets its minimum detectable effect (`stats.mde`, 80% power at the adjusted
level) and the trials an effect of the size seen would need; a verdict resting on fewer is flagged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from experiments import curvestats, stats
from experiments.claims import ALPHA, MARGIN
from experiments.sweeps.grid import Cell, Sweep, fmt_value, parse_assignment, parse_values

METRICS = ("ln_steps", "ln_steps_last10", "success", "return")
MAX_STEPS = 1000  # an episode that reaches it did not reach the goal (the envs' step limit)


# --------------------------------------------------------------------------------- metrics
def trial_metrics(steps: np.ndarray, returns: np.ndarray) -> dict[str, np.ndarray]:
    """Per-trial values of every metric, from [trials, episodes] arrays."""
    return {
        "ln_steps": stats.log_steps(steps).mean(axis=1),
        "ln_steps_last10": stats.log_steps(steps[:, -10:]).mean(axis=1),
        "success": (steps < MAX_STEPS).mean(axis=1),
        "return": returns.mean(axis=1),
    }


def clusters_of(layouts: np.ndarray) -> np.ndarray:
    """Resampling clusters: the layouts, or the trials themselves when all share one layout."""
    return layouts if len(np.unique(layouts)) > 1 else np.arange(len(layouts))


@dataclass
class CellData:
    steps: np.ndarray  # [trials, episodes]
    returns: np.ndarray
    clusters: np.ndarray  # [trials]

    @property
    def metrics(self) -> dict[str, np.ndarray]:
        return trial_metrics(self.steps, self.returns)


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


def summarize(sweep: Sweep, data: dict[int, CellData], n_boot: int) -> dict:
    """Per cell: every metric's mean with its 95% cluster-bootstrap interval."""
    out = {}
    for fixed, cells in groups(sweep):
        for c in cells:
            d = data[c.index]
            row = {
                "cell": c.label,
                "values": c.values,
                "group": group_title(fixed),
                "trials": int(d.steps.shape[0]),
                "episodes": int(d.steps.shape[1]),
                "clusters": int(len(np.unique(d.clusters))),
            }
            for name, v in d.metrics.items():
                b = stats.cluster_bootstrap(v, d.clusters, n_boot)
                row[name] = {"estimate": b["estimate"], "ci": b["ci"]}
            out[c.index] = row
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
    metric, body = "ln_steps", text.strip()
    head, sep, rest = body.partition(":")
    if sep and "=" not in head:
        metric, body = head.strip(), rest
    if metric not in METRICS:
        raise ValueError(f"contrast {text!r}: unknown metric {metric!r} ({', '.join(METRICS)})")
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
    return Contrast(body.strip(), metric, parsed[0], parsed[1])


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


def contrast_rows(con: Contrast, sweep: Sweep, data: dict[int, CellData], n_boot: int) -> list[dict]:
    """One row per combination of the fields the contrast does not name (verdicts: see `decide`)."""
    named = set(con.left)
    by_rest: dict[str, list[Cell]] = {}
    for cell in sweep.cells():
        rest = {p: v for p, v in cell.values.items() if p not in named}
        by_rest.setdefault(repr(sorted((p, fmt_value(v)) for p, v in rest.items())), []).append(cell)
    rows = []
    for cells in by_rest.values():
        a = next(c for c in cells if _match(c, con.left))
        b = next(c for c in cells if _match(c, con.right))
        da, db = data[a.index], data[b.index]
        diff = da.metrics[con.metric] - db.metrics[con.metric]  # paired by trial
        boot = stats.cluster_bootstrap(diff, da.clusters, n_boot)
        _, means, _ = stats.cluster_means(diff, da.clusters)
        p_two = min(1.0, 2 * min(stats.one_sided_p(means), stats.one_sided_p(-means)))
        rest = {path: v for path, v in a.values.items() if path not in named}
        rows.append(
            {
                "contrast": con.text,
                "metric": con.metric,
                "where": group_title(rest),
                "left": a.label,
                "right": b.label,
                "estimate": boot["estimate"],
                "ci": boot["ci"],
                "se": boot["se"],
                "p": p_two,
                "margin": _margin(con.metric, cells, data),
                "trials": int(len(diff)),
                "clusters": int(len(means)),
            }
        )
    return rows


def _margin(metric: str, cells: list[Cell], data: dict[int, CellData]) -> float:
    if metric.startswith("ln_steps"):
        return MARGIN
    if metric == "success":
        return 0.05
    lo, hi = curvestats.condition_levels({c.index: data[c.index].returns for c in cells})
    return curvestats.NEGLIGIBLE * max(hi - lo, 1e-9)


def evaluate_contrasts(contrasts: list[Contrast], sweep: Sweep, data: dict[int, CellData], n_boot: int) -> list[dict]:
    """Every row of every contrast, Holm-adjusted together, with verdicts and power."""
    rows = [r for con in contrasts for r in contrast_rows(con, sweep, data, n_boot)]
    adjusted = stats.holm({str(i): r["p"] for i, r in enumerate(rows)})
    m = max(len(rows), 1)
    for i, r in enumerate(rows):
        r["p_holm"] = adjusted[str(i)]
        r["verdict"] = decide(r["ci"], r["p_holm"], r["margin"], r["estimate"])
        r["mde"] = stats.mde(r["se"], ALPHA / (2 * m))  # two-sided at the Holm level of the smallest p
        effect = r["margin"] if r["verdict"] == "no meaningful difference" else abs(r["estimate"])
        needed = math.inf if effect <= 0 else max(2, math.ceil(r["trials"] * (r["mde"] / effect) ** 2))
        r["trials_needed"] = needed if math.isfinite(needed) else None
        r["underpowered"] = bool(needed > r["trials"])
    return rows


def decide(ci: list[float], p_holm: float, margin: float, estimate: float) -> str:
    if p_holm < ALPHA:
        return "A > B" if estimate > 0 else "A < B"
    if -margin < ci[0] and ci[1] < margin:
        return "no meaningful difference"
    return "inconclusive"


def warning_line(row: dict) -> str:
    need = "any number of" if row["trials_needed"] is None else f"about {row['trials_needed']}"
    return (
        f"warning: {row['metric']}: {row['contrast']} ({row['where']}): '{row['verdict']}' rests on "
        f"{row['trials']} trials; "
        f"the minimum detectable effect there is {row['mde']:.3f}, and an effect of the size seen needs "
        f"{need} trials (80% power at the Holm-adjusted level)"
    )
