"""`python -m experiments reproduce`: every condition with all its arms, figures, claims, REPORT.md.

The reproduction is a sweep: the named grid `paper` (experiments/sweeps/named.py: every condition with its
arms, the reproduction's trial plan) run by the sweep engine (experiments/sweeps/execute.py: cache,
batches, the local process pool or Ray with `ray=`, one progress bar), plus its pre-registered claims.
Pipeline: plan (which (condition, arm, trial) results are cached) -> run the missing trials -> evaluate
the declared claims (experiments/claims.py, experiments/evaluate.py) -> panels, figures, claims.json,
REPORT.md, timing.json.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import threading
import time
from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

from common.envs.maze import layout_pool
from experiments import figures, panels, report, report_runs
from experiments.conditions import DELAY_CONDITIONS, Condition, Scale, cluster_of, n_trials
from experiments.declarations import Declaration, get, of_run
from experiments.evaluate import N_BOOT, ArmData, evaluate_claims
from experiments.sweeps.execute import run_slots
from experiments.sweeps.named import paper_paths, paper_slots
from experiments.trialcache import EXTRA_FIELDS, read_json_or_none
from experiments.trials import TABLE, read_table, table_bytes, write_table


@dataclass
class ReproduceStats:
    trials: int
    trials_run: int
    trials_cached: int
    trials_shared: int
    total_s: float
    jobs: list[dict]


def git_commit() -> str:
    try:
        return (
            subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"],
                capture_output=True,
                text=True,
                cwd=os.path.dirname(os.path.abspath(__file__)),
                timeout=10,
            ).stdout.strip()
            or "?"
        )
    except (OSError, subprocess.SubprocessError):
        return "?"


def collect(conds: list[Condition], scale: Scale, cached: dict) -> tuple[dict, dict]:
    """(condition -> arm -> ArmData, condition -> arm -> extra per-episode arrays)."""
    data, extras = {}, {}
    for c in conds:
        n = n_trials(c, scale)
        data[c.name], extras[c.name] = {}, {}
        for arm in c.arms:
            recs = [cached[(c.name, arm, k)] for k in range(n)]
            data[c.name][arm] = ArmData(
                np.array([r["steps"] for r in recs], np.float64),
                np.array([r["return"] for r in recs], np.float64),
                np.array([r["spec"]["layout"] for r in recs]),
                np.array([cluster_of(c, scale, k) for k in range(n)]),
                c.stop_episode,
                c.is_taxi,
            )
            extras[c.name][arm] = {
                f: np.array([r[f] for r in recs], np.float64) for f in EXTRA_FIELDS if all(f in r for r in recs)
            }
    return data, extras


def analyse(
    conds: list[Condition], data: dict, extras: dict, out: str, n_boot: int, declaration: Declaration | None = None
) -> dict:
    """Claims (of the declaration; default 25 November's), panels, horizons, who-decides curves, learned lags;
    writes the figures."""
    by_name = {c.name: c for c in conds}
    result = {
        "n_boot": n_boot,
        "claims": evaluate_claims(data, n_boot, declaration),
        "panels": {},
        "horizons": {},
        "who_decides": {},
        "learned_lags": {},
    }
    for c in conds:
        result["panels"][c.name] = panels.condition_panels(data[c.name], extras[c.name], n_boot)
        result["horizons"][c.name] = panels.horizon(data[c.name], c.stop_episode)
        curves = panels.who_decides_curves(data[c.name], extras[c.name])
        if curves and not c.name.startswith("delay-"):
            result["who_decides"][c.name] = curves
        figures.plot_condition(c.title, data[c.name], c.stop_episode, os.path.join(out, f"{c.name}.png"))
    for name in DELAY_CONDITIONS:
        if name not in data:
            continue
        c = by_name[name]
        E = next(iter(data[name].values())).steps.shape[1]
        true = [float((1.0 - c.observer.lag_cdf(e)).sum()) for e in range(E)]  # E[lag] = sum of 1 - CDF
        learned = {
            arm: extras[name][arm]["mean_lag"].mean(axis=0).tolist() for arm in data[name] if arm.endswith("/learned")
        }
        result["learned_lags"][name] = {"true": true, "learned": learned}
    figures.plot_who_decides(result["who_decides"], os.path.join(out, "who-decides.png"))
    figures.plot_learned_lags(result["learned_lags"], os.path.join(out, "learned-lags.png"))
    return result


def _where_and_when(workers: int, ray: str | None, load_start: list[float], load_max: float, started: str) -> dict:
    """timing.json's facts of the machine, the code and the load a run had (in the file's key order)."""
    return {
        "workers": workers,
        "ray": ray,
        "cpus": os.cpu_count(),
        "machine": machine(),
        "python": platform.python_version(),
        "commit": git_commit(),
        "load_average_at_start": load_start,
        "load_average_at_end": list(os.getloadavg()),
        "load_average_max": load_max,
        "started_utc": started,
    }


def reproduce(
    conds: list[Condition],
    scale: Scale,
    out: str,
    workers: int = 2,
    progress: bool = True,
    on_progress: Callable[[int, int], None] | None = None,
    argv: list[str] | None = None,
    n_boot: int = N_BOOT,
    ray: str | None = None,
    declaration: str | None = None,
    replicate: int | None = None,
    against: str | None = None,
) -> ReproduceStats:
    """Run (or read from the cache) every trial, then write figures, claims.json, REPORT.md, timing.json.
    `declaration`: its id (default: the newest), whose arms are run and claims decided; timing.json records it and
    `replicate` (which of its runs `scale` is; None: none, as --quick). `against`: the other run's claims.json.
    `on_progress(trials_done, trials_total)` is called in this process whenever a trial finishes (an exception
    raised from it stops the run; finished trials stay cached). `ray`: run the trials as Ray tasks on that cluster
    (auto, local or HOST:PORT) instead of `workers` local processes."""
    t_start = time.perf_counter()
    conds = get(declaration).conditions(conds)
    os.makedirs(out, exist_ok=True)
    cache_dir = os.path.join(out, "cache")
    load_start = list(os.getloadavg())
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    with LoadSampler() as load:
        run_plan, run = run_slots(
            paper_slots(conds, scale), paper_paths(cache_dir), workers, ray, progress, on_progress
        )
    cached, infos, total, reused = run_plan.records, run.jobs, run.cell_trials, run.reused
    done0, slots_todo, todo = run.cached, run.filled, run_plan.todo
    run_wall = time.perf_counter() - t_start
    table_path = os.path.join(out, TABLE)
    write_table(table_path, conds, scale, cached)
    timing = {
        "total_s": time.perf_counter() - t_start,
        "run_s": run_wall,
        "trials": total,
        "trials_run": slots_todo,
        "trials_computed": len(todo),
        "trials_cached": done0 - reused,
        "trials_shared": reused + (slots_todo - len(todo)),
        **_where_and_when(workers, ray, load_start, load.max, started),
        "worker_end_spread_s": _end_spread(infos),
        "cpu_s_per_worker": _cpu_per_worker(infos),
        "scale": scale.__dict__,
        "declaration": get(declaration).id,
        "replicate": replicate,
        "env": {k: os.environ.get(k) for k in ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")},
        "trial_steps": int(sum(info["trial_steps"] for info in infos)),
        "jobs": [{k: v for k, v in info.items() if k != "steps"} for info in infos],
    }
    timing_path = os.path.join(out, "timing.json")
    previous_timing = read_json_or_none(timing_path) or {}
    # The last run that simulated every trial (a from-scratch timing) is kept beside this run's own figures,
    # so a cached re-run never passes off as the cost of the reproduction.
    timing["from_scratch"] = timing["trials_cached"] == 0 and timing["trials_computed"] > 0
    timing["last_from_scratch"] = (
        _scratch_summary(timing) if timing["from_scratch"] else previous_timing.get("last_from_scratch")
    )
    with open(timing_path, "w") as fh:
        json.dump(timing, fh, indent=1)
    old = read_json_or_none(os.path.join(out, "claims.json")) or {}
    previous = _previous_verdicts(old, resumed=timing["trials_cached"] > 0)
    report_from_table(table_path, out, timing, argv or ["reproduce"], n_boot, previous, against)
    # The analysis after total_s (REPORT.md states total_s; the whole command took total_s + analysis_s).
    timing["analysis_s"] = time.perf_counter() - t_start - timing["total_s"]
    with open(timing_path, "w") as fh:
        json.dump(timing, fh, indent=1)
    with open(os.path.join(out, ".gitignore"), "w") as fh:
        fh.write("cache/\n")
    return ReproduceStats(
        total,
        slots_todo,
        done0 - reused,
        reused + (slots_todo - len(todo)),
        timing["total_s"] + timing["analysis_s"],
        infos,
    )


def report_from_table(
    table_path: str,
    out: str,
    timing: dict,
    argv: list[str],
    n_boot: int = N_BOOT,
    previous: dict | None = None,
    against: str | None = None,
) -> dict:
    """Every verdict, interval and figure from the per-trial table alone (no trial is run), decided under the
    declaration its run recorded in `timing` (none recorded: 25 November's): writes `out`/claims.json, REPORT.md
    and the figures; returns claims.json's content. `against`: the other run's claims.json (settlement table)."""
    os.makedirs(out, exist_ok=True)
    table = read_table(table_path)
    decl = of_run(timing)
    result = analyse(table.conditions, table.data, table.extras, out, n_boot, decl)
    if decl.id != of_run({}).id:  # (claims.json of the first declaration's runs keep their form)
        result["declaration"] = decl.id
    result["previous"] = previous or {}
    digest = hashlib.sha256(table_bytes(table_path)).hexdigest()  # which table these numbers come from
    result["table"] = {"file": os.path.basename(table_path), "sha256": digest}
    with open(os.path.join(out, "claims.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    _, drawn = layout_pool()
    settle = report_runs.settlement_against(result, against, timing.get("replicate")) if against else None
    write_report(os.path.join(out, "REPORT.md"), result, table.conditions, timing, argv, drawn, out, settle)
    return result


def machine() -> dict:
    """Which machine ran it: the CPU model, the cores this process may use, the host name."""
    model = "?"
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), "?")
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {"cpu_model": model, "cores_usable": usable, "host": platform.node(), "system": platform.platform()}


def _scratch_summary(timing: dict) -> dict:
    """What the report header says about a run that computed every trial."""
    keys = (
        "total_s",
        "run_s",
        "trials",
        "trials_computed",
        "trial_steps",
        "workers",
        "cpus",
        "machine",
        "commit",
        "load_average_at_start",
        "load_average_at_end",
        "load_average_max",
        "worker_end_spread_s",
        "cpu_s_per_worker",
        "scale",
        "env",
        "started_utc",
    )
    return {k: timing.get(k) for k in keys}


def _previous_verdicts(old: dict, resumed: bool) -> dict:
    """Verdicts of the run before this one. A run that read trials from this directory's cache (a re-plot, a run
    resumed after an interruption, the rest of an `--only` part) continues the run whose report is there: it keeps
    the previous verdicts that report had, not that report's own (partial) verdicts."""
    if resumed:
        return old.get("previous", {})
    return {cid: c.get("verdict") for cid, c in old.get("claims", {}).items()}


class LoadSampler:
    """The machine's 1-minute load average, sampled every `every` seconds while the trials run: its maximum
    goes into timing.json and the report, beside the values at the start and the end."""

    def __init__(self, every: float = 10.0):
        self.every, self.max = every, os.getloadavg()[0]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self.max = max(self.max, os.getloadavg()[0])

    def __enter__(self) -> LoadSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.max = max(self.max, os.getloadavg()[0])


def _end_spread(infos: list[dict]) -> float | None:
    """Seconds between the first and the last worker finishing its last job (None for one worker)."""
    last: dict = {}
    for info in infos:
        if "ended_at" in info:
            key = (info.get("host"), info["pid"])
            last[key] = max(last.get(key, 0.0), info["ended_at"])
    return float(max(last.values()) - min(last.values())) if len(last) > 1 else None


def _cpu_per_worker(infos: list[dict]) -> dict[str, float]:
    out: dict[str, float] = {}
    for info in infos:
        out[str(info["pid"])] = out.get(str(info["pid"]), 0.0) + info["cpu_s"]
    return out


def write_report(
    path: str,
    result: dict,
    conds: list[Condition],
    timing: dict,
    argv: list[str],
    drawn: dict,
    out: str,
    settle: list[dict] | None = None,
) -> None:
    lines = report.body(result, conds, timing, argv, drawn, out, settle)
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
