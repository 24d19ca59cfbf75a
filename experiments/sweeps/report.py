"""`run_sweep`: compute (or read from the cache) every trial of a sweep, then write its tables, figures,
contrasts and SWEEP.md.

Output folder: `sweep.yaml` (the sweep as run), `trials.csv` / `trials.parquet` (tidy), `summary.csv` and
`summary.json` (per cell), `contrasts.json`, `group-NN.png` (one per group of cells), `timing.json`,
`SWEEP.md`, and `cache/` (one file per distinct trial; kept out of git by a .gitignore).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np
import yaml

from experiments.evaluate import N_BOOT
from experiments import stats
from experiments.sweeps import analysis, execute, tables
from experiments.sweeps.grid import Sweep
from experiments.trialcache import read_json_or_none


@dataclass
class SweepResult:
    run: execute.RunStats
    total_s: float
    summary: dict
    contrasts: list[dict]
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)


def run_sweep(
    sweep: Sweep,
    out: str,
    workers: int = 2,
    ray: str | None = None,
    progress: bool = True,
    cache_dir: str | None = None,
    n_boot: int = N_BOOT,
    on_trial=None,
    command: str = "",
) -> SweepResult:
    t0 = time.perf_counter()
    contrasts = [analysis.parse_contrast(c, sweep) for c in sweep.contrasts]  # bad ones fail before running
    os.makedirs(out, exist_ok=True)
    cache_dir = cache_dir or os.path.join(out, "cache")
    with open(os.path.join(out, "sweep.yaml"), "w") as fh:
        yaml.safe_dump(sweep.record(), fh, sort_keys=False)
    p, run = execute.execute(sweep, cache_dir, workers, ray, progress, on_trial)

    data = cell_data(sweep, p.records)
    summary = analysis.summarize(sweep, data, n_boot)
    rows = analysis.evaluate_contrasts(contrasts, sweep, data, n_boot)
    warnings = [analysis.warning_line(r) for r in rows if r["underpowered"]]
    files = [
        *tables.write_tidy(tables.tidy_table(sweep, p.records), out),
        tables.write_summary(summary, sweep, out),
        *tables.plot_groups(sweep, data, out),
    ]
    with open(os.path.join(out, "summary.json"), "w") as fh:
        json.dump({str(k): v for k, v in summary.items()}, fh, indent=1, default=_plain)
    with open(os.path.join(out, "contrasts.json"), "w") as fh:
        json.dump(rows, fh, indent=1)
    total_s = time.perf_counter() - t0
    timing = {
        "total_s": total_s,
        "run_s": run.run_s,
        "backend": run.backend,
        "workers": workers,
        "ray": ray,
        "cell_trials": run.cell_trials,
        "trials_computed": run.computed,
        "cell_trials_filled": run.filled,
        "cell_trials_cached": run.cached,
        "jobs": run.jobs,
    }
    timing_path = os.path.join(out, "timing.json")
    previous = read_json_or_none(timing_path)
    if run.computed == 0 and previous and previous.get("trials_computed", 0) > 0:
        previous["replot_s"] = total_s  # a re-plot keeps the timing of the run that computed the trials
        timing = previous
    with open(timing_path, "w") as fh:
        json.dump(timing, fh, indent=1)
    write_markdown(os.path.join(out, "SWEEP.md"), sweep, summary, rows, warnings, timing, command)
    with open(os.path.join(out, ".gitignore"), "w") as fh:
        fh.write("cache/\n")
    files += [os.path.join(out, n) for n in ("summary.json", "contrasts.json", "timing.json", "SWEEP.md")]
    return SweepResult(run, total_s, summary, rows, warnings, files)


def cell_data(sweep: Sweep, records: dict) -> dict[int, analysis.CellData]:
    out = {}
    for c in sweep.cells():
        recs = [records[(c.index, k)] for k in range(sweep.trials)]
        layouts = np.array([r["spec"]["layout"] for r in recs])
        out[c.index] = analysis.CellData(
            np.array([r["steps"] for r in recs], np.float64),
            np.array([r["return"] for r in recs], np.float64),
            analysis.clusters_of(layouts),
        )
    return out


def _plain(v):
    if isinstance(v, tuple):
        return list(v)
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"not JSON: {type(v).__name__}")


def _iv(iv: dict | None, digits: int = 2) -> str:
    if not iv:
        return ""
    return f"{iv['estimate']:.{digits}f} [{iv['ci'][0]:.{digits}f}, {iv['ci'][1]:.{digits}f}]"


def write_markdown(
    path: str, sweep: Sweep, summary: dict, rows: list[dict], warnings: list[str], timing: dict, command: str
) -> None:
    lines = [
        f"# Sweep `{sweep.name}` (generated)",
        "",
        f"`{command or 'python -m experiments sweep'}`: {len(sweep.cells())} cells x {sweep.trials} trials, "
        f"wall {timing['total_s']:.1f} s ({timing['backend']}). Tidy table: `trials.csv` / `trials.parquet`. "
        "Per trial: mean ln steps per episode (all episodes, last 10), share of episodes that reach the goal, "
        "mean return; per cell: mean over trials with a 95% layout-cluster bootstrap interval (the "
        "reproduction's metrics and intervals). Every cell runs the same trials (layout, seed), so contrasts "
        "are paired.",
        "",
        "## Cells",
        "",
        "| cell | trials (clusters) | ln steps | ln steps, last 10 | success | return |",
        "|---|---|---|---|---|---|",
    ]
    for row in summary.values():
        lines.append(
            f"| {row['cell']} | {row['trials']} ({row['clusters']}) | {_iv(row['ln_steps'])} | "
            f"{_iv(row['ln_steps_last10'])} | {_iv(row['success'])} | {_iv(row['return'])} |"
        )
    groups = analysis.groups(sweep)
    lines += ["", "## Figures", ""]
    for g, (fixed, _) in enumerate(groups):
        lines += [f"![{analysis.group_title(fixed)}](group-{g:02d}.png)", ""]
    if rows:
        lines += [
            "## Contrasts",
            "",
            "Left minus right, paired by trial; p: two-sided t-test on the layout means, Holm-adjusted over all rows.",
            "",
            "| contrast | where | estimate [95% CI] | p (Holm) | margin | verdict | MDE | trials needed |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in rows:
            need = "-" if r["trials_needed"] is None else str(r["trials_needed"])
            flag = " (underpowered)" if r["underpowered"] else ""
            lines.append(
                f"| {r['metric']}: {r['contrast']} | {r['where']} | {_iv(r, 3)} | "
                f"{stats.fmt_p(r['p_holm'])} | "
                f"{r['margin']:.3f} | **{r['verdict']}**{flag} | {r['mde']:.3f} | {need} |"
            )
        lines.append("")
    if warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in warnings] + [""]
    with open(path, "w") as fh:
        fh.write("\n".join(lines))


def print_outcome(result: SweepResult, out: str, stream=None) -> None:
    stream = stream or sys.stdout
    r = result.run
    ran = f"{r.computed} trials computed on {r.backend}, filling {r.filled}" if r.computed else "nothing to compute"
    print(
        f"{r.cell_trials} cell-trials ({ran}; {r.cached} from the cache) in {result.total_s:.1f} s; "
        f"wrote {out}/SWEEP.md, trials.csv, "
        "trials.parquet, summary.csv, *.png",
        file=stream,
    )
    for row in result.contrasts:
        print(f"  {row['metric']}: {row['contrast']} [{row['where']}]: {_iv(row, 3)} -> {row['verdict']}", file=stream)
    for w in result.warnings:
        print(w, file=sys.stderr)
