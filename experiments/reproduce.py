"""`python -m experiments reproduce`: every condition of the paper with all four agents, figures, claims.

Pipeline: plan (which (condition, agent, trial) results are cached) -> run the missing trials in batches
on worker processes -> figures, claims.json, REPORT.md, timing.json, curves.npz.

Caching: each trial's result is a JSON file `cache/<condition>/<agent>/<trial>-<key>.json`, written
atomically by the worker the moment the trial finishes, where key hashes everything that determines the
result (environment, layout, seed, episodes, agent config, observer config, RESULTS_VERSION). An
interrupted run therefore resumes with only the missing trials, and a second run only re-plots. A trial
whose agent ignores feedback (DQN) does not depend on the observer, so its key leaves the observer out
and the six Maze MDP conditions share one set of DQN trials (run once, stored under each condition).

Batching: all missing trials of one environment kind, whatever their condition and agent, go into the
same lockstep batches (they share observation and action spaces), split over the workers. Trials that
are slow to finish (agents stuck in 1000-step episodes) then share their ticks with the stragglers of
other conditions instead of each condition paying for its own tail. Results do not depend on the
batching (tests/experiments/test_batching.py).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import multiprocessing as mp
import os
import platform
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from experiments import claims as claims_mod
from experiments.conditions import ALGOS, Condition, trial_spec
from experiments.runner import TrialResult, TrialSpec, run_trials

RESULTS_VERSION = 1
"""Bump when a change to the core changes results, so cached trials are recomputed."""

AGENT_COLORS = {"dqn": "#1f77b4", "dqn-rs": "#ff7f0e", "deep-tamer": "#2ca02c", "dqn-tamer": "#d62728"}


# ------------------------------------------------------------------------------------ caching
def _record(obj) -> dict:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def trial_key(spec: TrialSpec) -> str:
    agent = spec.agent
    uses_feedback = agent.train_h or agent.reward_shaping
    payload = {"version": RESULTS_VERSION, "env": spec.env, "layout": spec.layout, "seed": spec.seed,
               "episodes": spec.episodes, "agent": _record(agent),
               "observer": _record(spec.observer) if uses_feedback else None}
    return hashlib.sha1(json.dumps(payload, sort_keys=True, default=list).encode()).hexdigest()[:16]


@dataclass
class Slot:
    cond: str
    algo: str
    trial: int
    path: str


@dataclass
class Task:
    key: str
    spec: TrialSpec
    slots: list[Slot] = field(default_factory=list)


def result_record(key: str, result: TrialResult) -> dict:
    eps = result.episodes
    return {"key": key, "version": RESULTS_VERSION, "spec": {
                "env": result.spec.env, "layout": result.spec.layout, "seed": result.spec.seed,
                "episodes": result.spec.episodes, "agent": _record(result.spec.agent),
                "observer": _record(result.spec.observer)},
            "total_steps": result.total_steps,
            "return": [e["return"] for e in eps], "steps": [e["steps"] for e in eps],
            "feedback_given": [e["feedback_given"] for e in eps],
            "feedback_credited": [e["feedback_credited"] for e in eps]}


def write_json_atomic(path: str, obj) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(obj, fh)
    os.replace(tmp, path)


def read_cached(path: str, key: str) -> dict | None:
    try:
        with open(path) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    return rec if rec.get("key") == key else None


def plan(conds: list[Condition], trials: int, cache_dir: str) -> tuple[dict, list[Task], int]:
    """(cached records by (cond, algo, trial), tasks to run, number of slots reused from another
    condition's identical trial)."""
    cached: dict[tuple[str, str, int], dict] = {}
    by_key: dict[str, Task] = {}
    for c in conds:
        for algo in ALGOS:
            for k in range(trials):
                spec = trial_spec(c, algo, k)
                key = trial_key(spec)
                path = os.path.join(cache_dir, c.name, algo, f"{k:03d}-{key}.json")
                rec = read_cached(path, key)
                if rec is not None:
                    cached[(c.name, algo, k)] = rec
                    continue
                by_key.setdefault(key, Task(key, spec)).slots.append(Slot(c.name, algo, k, path))
    # A trial that only lacks its own file but exists under another condition (same key) is copied.
    reused = 0
    todo = []
    known = {rec["key"]: rec for rec in cached.values()}
    for key, task in by_key.items():
        if key in known:
            for s in task.slots:
                write_json_atomic(s.path, known[key])
                cached[(s.cond, s.algo, s.trial)] = known[key]
                reused += 1
        else:
            todo.append(task)
    return cached, todo, reused


# Rough cost of an episode (CPU, arbitrary units) by environment, to balance jobs between workers:
# environment steps per episode averaged over a run (Maze about 150, POMDP about 80, Taxi about 1000 as
# no agent learns Taxi within the run) times the relative cost of a step (Taxi: larger observation,
# updates every 4 steps). Measured from full runs (docs/results/timing.json).
EPISODE_COST = {"maze": 150.0, "maze-pomdp": 80.0, "taxi": 1000.0 * 0.6}


def job_cost(tasks: list[Task]) -> float:
    return sum(t.spec.episodes * EPISODE_COST.get(t.spec.env, 300.0) for t in tasks)


def make_jobs(tasks: list[Task], workers: int) -> list[list[Task]]:
    """Batches for the workers, largest first.

    All trials of one environment kind form one batch (one lockstep tail: the few trials stuck in
    1000-step episodes then share ticks instead of each batch paying for its own). A kind is split
    into interleaved parts (each with a similar mix of conditions and agents) only when it is more
    than a worker's fair share of the work, so that all workers stay busy."""
    by_env: dict[str, list[Task]] = {}
    for t in tasks:
        by_env.setdefault(t.spec.env, []).append(t)
    total = sum(job_cost(ts) for ts in by_env.values())
    share = total / max(workers, 1)
    jobs = []
    for env, ts in by_env.items():
        ts = sorted(ts, key=lambda t: (t.spec.agent.algo, t.slots[0].cond if t.slots else "", t.slots[0].trial if t.slots else 0))
        parts = max(1, min(workers, len(ts), int(round(job_cost(ts) / max(share, 1e-9)))))
        jobs.extend([ts[i::parts] for i in range(parts)])
    jobs.sort(key=lambda j: -job_cost(j))
    return jobs


# ------------------------------------------------------------------------------------- running
def _run_job(job_id: int, tasks: list[Task], emit: Callable[[tuple], None]) -> dict:
    """Run one batch; write each trial's cache files when it finishes; report progress via emit:
    ("progress", fraction of trials) as episodes end, ("trial", slots, fraction already reported) when
    a trial is done."""
    specs = [t.spec for t in tasks]
    reported = [0.0] * len(tasks)
    unsent = [0.0]
    last = [time.perf_counter()]

    def on_episode(i: int, record: dict) -> None:
        step = len(tasks[i].slots) / max(specs[i].episodes, 1)
        reported[i] += step
        unsent[0] += step
        now = time.perf_counter()
        if now - last[0] > 0.25:
            emit(("progress", unsent[0]))
            unsent[0] = 0.0
            last[0] = now

    def on_trial_done(i: int, result: TrialResult) -> None:
        rec = result_record(tasks[i].key, result)
        for s in tasks[i].slots:
            write_json_atomic(s.path, rec)
        emit(("progress", unsent[0]))
        unsent[0] = 0.0
        emit(("trial", len(tasks[i].slots), reported[i]))

    t0, c0 = time.perf_counter(), time.process_time()
    profile: dict = {}
    results = run_trials(specs, on_episode=on_episode, on_trial_done=on_trial_done, profile=profile)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"job": job_id, "pid": os.getpid(), "env": specs[0].env, "trials": len(specs), "wall_s": wall, "cpu_s": cpu,
            "trial_steps": int(sum(r.total_steps for r in results)),
            "max_trial_steps": int(max(r.total_steps for r in results)),
            "by_running_trials": profile,
            "steps": {tasks[i].key: r.total_steps for i, r in enumerate(results)}}


def _worker(jobs_q, msg_q, parent: int) -> None:
    import torch
    torch.set_num_threads(1)

    def emit(msg):
        if os.getppid() != parent:  # the parent is gone: stop (finished trials are already cached)
            raise SystemExit(1)
        msg_q.put(msg)

    while True:
        item = jobs_q.get()
        if item is None:
            return
        job_id, tasks = item
        try:
            info = _run_job(job_id, tasks, emit)
            msg_q.put(("job", info))
        except BaseException as exc:  # report, then die: the parent stops the run
            msg_q.put(("error", f"job {job_id}: {type(exc).__name__}: {exc}"))
            raise


def run_jobs(jobs: list[list[Task]], workers: int, on_message: Callable[[tuple], None]) -> list[dict]:
    """Run jobs on `workers` processes (in this process when workers <= 1). Returns the job infos."""
    infos = []
    if workers <= 1:
        for j, tasks in enumerate(jobs):
            info = _run_job(j, tasks, on_message)
            infos.append(info)
            on_message(("job", info))
        return infos
    ctx = mp.get_context("spawn")
    jobs_q, msg_q = ctx.Queue(), ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(jobs_q, msg_q, os.getpid()), daemon=True)
             for _ in range(min(workers, len(jobs)))]
    old_term = signal.signal(signal.SIGTERM, _raise_exit) if threading.current_thread() is threading.main_thread() else None
    for p in procs:
        p.start()
    for j, tasks in enumerate(jobs):
        jobs_q.put((j, tasks))
    for _ in procs:
        jobs_q.put(None)
    try:
        while len(infos) < len(jobs):
            try:
                msg = msg_q.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in procs if not p.is_alive() and p.exitcode not in (0, None)]
                if dead:
                    raise RuntimeError(f"a worker died (exit code {dead[0].exitcode})")
                continue
            if msg[0] == "error":
                raise RuntimeError(msg[1])
            if msg[0] == "job":
                infos.append(msg[1])
            on_message(msg)
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
    return infos


def _raise_exit(signum, frame):
    raise SystemExit(128 + signum)


# ---------------------------------------------------------------------------------------- output
def plot_condition(cond: Condition, returns: dict[str, np.ndarray], path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=100)
    lows = []
    for algo in ALGOS:
        if algo not in returns:
            continue
        mid, lo, hi = claims_mod.curve_band(returns[algo])
        x = np.arange(1, len(mid) + 1)
        ax.plot(x, mid, color=AGENT_COLORS[algo], lw=1.5, label=claims_mod.AGENT_NAMES[algo])
        ax.fill_between(x, lo, hi, color=AGENT_COLORS[algo], alpha=0.15, lw=0)
        lows.append(np.quantile(mid, 0.05))
    if cond.stop_episode is not None:
        ax.axvline(cond.stop_episode + 0.5, color="black", ls="--", lw=1)
        ax.text(cond.stop_episode + 1, 0.02, "feedback stops", transform=ax.get_xaxis_transform(), fontsize=8)
    # Keep the first, random-policy episodes from flattening the learning phase.
    top = max(float(np.max(claims_mod.curve_band(R)[2])) for R in returns.values())
    bottom = min(lows)
    ax.set_ylim(bottom - 0.1 * (top - bottom), top + 0.05 * (top - bottom))
    n = next(iter(returns.values())).shape[0]
    ax.set_title(f"{cond.title}\n10%-trimmed mean of {n} trials, 95% bootstrap band", fontsize=9)
    ax.set_xlabel("episode")
    ax.set_ylabel("return per episode")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _fmt_ep(v: float, iv: dict) -> str:
    return "never" if v >= iv["censored_at"] else f"{v:.0f}"


def _fmt(iv: dict, digits: int = 2) -> str:
    return f"{iv['estimate']:.{digits}f} [{iv['ci'][0]:.{digits}f}, {iv['ci'][1]:.{digits}f}]"


def write_report(path: str, evaluation: dict, conds: list[Condition], timing: dict, argv: list[str]) -> None:
    ev = evaluation
    lines = ["# Reproduction of the paper's claims (generated)", "",
             f"Generated by `python -m experiments {' '.join(argv)}` at commit `{timing.get('commit', '?')}`; "
             f"{ev['method']['trials']} trials per agent and condition, wall {timing['total_s']:.0f} s on "
             f"{timing['workers']} worker process(es). Every verdict below is computed from the intervals by "
             "`experiments/claims.py`; nothing in this file is written by hand. Hyper-parameters and what was "
             "tried: [docs/hyperparameters.md](../hyperparameters.md).", "",
             "## Verdicts", "", "| claim | verdict | statement |", "|---|---|---|"]
    for cid, c in ev["claims"].items():
        lines.append(f"| {cid} | **{c['verdict']}** | {c['text']} |")
    lines += ["", "## Method", "",
              f"- Per trial: return per episode. Aggregate: {int(ev['method']['trim'] * 100)}%-trimmed mean across "
              f"trials; intervals: {int(ev['method']['ci_level'] * 100)}% percentile bootstrap over trials "
              f"({ev['method']['n_boot']} resamples), paired by trial (same layout and seed for every agent "
              "and condition).",
              "- Metrics: AUC = mean return over all episodes; final = mean over the last 10% of episodes; "
              "initial = mean over the first 10; to90 = first episode (from 1) where the 5-episode moving average of "
              "the trimmed-mean curve reaches 90% of the way from the condition's start level (lowest "
              "first-episode level of any agent) to its best level (best final level of any agent); "
              "post-stop gain = last 10 episodes minus the 10 before feedback stops.",
              f"- Verdict rules: a `greater` test is reproduced when its CI is above 0, not reproduced when it is "
              f"below 0 or entirely within +-{ev['method']['negligible']:.0%} of the condition's return scale "
              f"(best level - start level), inconclusive otherwise; an `equivalent` test is reproduced when its "
              f"CI is within +-{ev['method']['equivalence']:.0%} of the scale, not reproduced when entirely "
              "outside on one side; a `not_greater` test is reproduced when its CI is below that margin, not "
              "reproduced when above it. A claim is reproduced when all its tests are, not reproduced when "
              "any is not, inconclusive otherwise.", ""]
    for cid, c in ev["claims"].items():
        lines += [f"## {cid}: {c['verdict']}", "", c["text"], "",
                  "| test | kind | estimate [95% CI] | margin | verdict |", "|---|---|---|---|---|"]
        for s in c["subtests"]:
            if s["verdict"] == claims_mod.NOT_EVALUATED:
                lines.append(f"| {s['test']} | {s['kind']} | (conditions not run) | | not evaluated |")
            else:
                lines.append(f"| {s['test']} | {s['kind']} | {_fmt(s, 3)} | {s['margin']:.3f} | {s['verdict']} |")
        lines.append("")
    lines += ["## Conditions", ""]
    for c in conds:
        if c.name not in ev["conditions"]:
            continue
        cd = ev["conditions"][c.name]
        lines += [f"### {c.title} (`{c.name}`)", "", f"![{c.name}]({c.name}.png)", "",
                  f"{cd['episodes']} episodes; start level {cd['start_level']:.2f}, best level "
                  f"{cd['best_level']:.2f}. {c.figure}.", ""]
        stop = cd["stop"] is not None
        head = "| agent | AUC | final | initial | episodes to 90% |" + (" post-stop gain |" if stop else "")
        lines += [head, "|---" * (6 if stop else 5) + "|"]
        for algo, row in cd["agents"].items():
            to90 = row["to90"]
            t90 = ("never" if to90["estimate"] >= to90["censored_at"] else f"{to90['estimate']:.0f}") + \
                f" [{_fmt_ep(to90['ci'][0], to90)}, {_fmt_ep(to90['ci'][1], to90)}]"
            cells = [claims_mod.AGENT_NAMES[algo], _fmt(row["auc"]), _fmt(row["final"]), _fmt(row["initial"]), t90]
            if stop:
                cells.append(_fmt(row["post_stop"]))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Timing", "", f"Total wall {timing['total_s']:.1f} s for {timing['trials']} trial results "
              f"({timing['trials_per_s']:.2f} per second): {timing['trials_computed']} trials simulated, "
              f"{timing['trials_shared']} results shared between conditions (DQN ignores feedback, so its trials "
              f"are the same in every Maze MDP condition), {timing['trials_cached']} read from the cache. "
              "CPU seconds per worker: " + ", ".join(f"{v:.0f}" for v in timing.get("cpu_s_per_worker", {}).values())
              + f"; load average at the end {timing.get('load_average_at_end', [0])[0]:.1f}. Conditions share "
              "batches, so the wall time per condition in timing.json is each batch's wall time shared out in "
              "proportion to the environment steps of the condition's trials.", ""]
    with open(path, "w") as fh:
        fh.write("\n".join(lines))


def _cpu_per_worker(infos: list[dict]) -> dict[str, float]:
    """CPU seconds each worker process spent in its jobs: on dedicated cores the run's wall time is
    about the largest of these (plus start-up and plotting), whatever else the machine was doing."""
    out: dict[str, float] = {}
    for info in infos:
        out[str(info["pid"])] = out.get(str(info["pid"]), 0.0) + info["cpu_s"]
    return out


def _read_json(path: str):
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=os.path.dirname(os.path.abspath(__file__)), timeout=10).stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


# ------------------------------------------------------------------------------------------ main
@dataclass
class ReproduceStats:
    trials: int
    trials_run: int
    trials_cached: int
    trials_shared: int
    total_s: float
    jobs: list[dict]


def reproduce(conds: list[Condition], trials: int, out: str, workers: int = 2, progress: bool = True,
              on_progress: Callable[[int, int], None] | None = None, argv: list[str] | None = None,
              n_boot: int = claims_mod.N_BOOT) -> ReproduceStats:
    """Run (or read from the cache) every trial, then write figures, claims.json, REPORT.md, timing.json.

    `on_progress(trials_done, trials_total)` is called in this process whenever a trial finishes (an
    exception raised from it stops the run; finished trials stay cached)."""
    t_start = time.perf_counter()
    os.makedirs(out, exist_ok=True)
    cache_dir = os.path.join(out, "cache")
    cached, todo, reused = plan(conds, trials, cache_dir)
    total = len(conds) * len(ALGOS) * trials
    done0 = len(cached)
    slots_todo = sum(len(t.slots) for t in todo)
    jobs = make_jobs(todo, workers)
    bar = None
    if progress and todo:
        from tqdm import tqdm
        bar = tqdm(total=float(total), initial=float(done0), desc="trials", unit="trial", file=sys.stderr,
                   bar_format="{desc}: {n:.0f}/{total:.0f} trials |{bar}| {elapsed} elapsed, {remaining} left")
    done = [done0]
    partial = [0.0]  # progress of unfinished trials, in trials

    def on_message(msg: tuple) -> None:
        kind = msg[0]
        if kind == "progress":
            partial[0] += msg[1]
        elif kind == "trial":
            done[0] += msg[1]
            partial[0] -= msg[2]
            if on_progress is not None:
                on_progress(done[0], total)
        if bar is not None and kind in ("progress", "trial"):
            bar.n = min(float(total), done[0] + max(partial[0], 0.0))
            bar.refresh()

    t_run = time.perf_counter()
    infos = run_jobs(jobs, workers, on_message) if jobs else []
    run_wall = time.perf_counter() - t_run
    if bar is not None:
        bar.n = float(total)
        bar.close()
    cached, todo_left, _ = plan(conds, trials, cache_dir)
    if todo_left:
        raise RuntimeError(f"{len(todo_left)} trials missing after the run")

    returns = {c.name: {a: np.array([cached[(c.name, a, k)]["return"] for k in range(trials)]) for a in ALGOS}
               for c in conds}
    steps = {c.name: {a: np.array([cached[(c.name, a, k)]["total_steps"] for k in range(trials)]) for a in ALGOS}
             for c in conds}
    np.savez_compressed(os.path.join(out, "curves.npz"),
                        **{f"{cn}/{a}": R.astype(np.float32) for cn, d in returns.items() for a, R in d.items()})
    evaluation = claims_mod.evaluate(returns, {c.name: c.stop_episode for c in conds}, n_boot=n_boot)
    for c in conds:
        plot_condition(c, returns[c.name], os.path.join(out, f"{c.name}.png"))
    total_s = time.perf_counter() - t_start

    # Wall per condition: conditions share batches, so each job's wall is attributed to its trials in
    # proportion to their environment steps (a trial's cost is about proportional to its steps).
    per_cond = {c.name: 0.0 for c in conds}
    key_slots = {t.key: t.slots for t in todo}
    for info in infos:
        for key, st in info["steps"].items():
            share = info["wall_s"] * st / max(info["trial_steps"], 1) / len(key_slots[key])
            for s in key_slots[key]:
                per_cond[s.cond] += share
    timing = {
        "total_s": total_s, "run_s": run_wall, "trials": total, "trials_per_s": total / max(total_s, 1e-9),
        "trials_run": slots_todo, "trials_computed": len(todo), "trials_cached": done0 - reused,
        "trials_shared": reused + (slots_todo - len(todo)), "workers": workers, "cpus": os.cpu_count(),
        "python": platform.python_version(), "commit": git_commit(),
        "load_average_at_end": list(os.getloadavg()),
        "cpu_s_per_worker": _cpu_per_worker(infos),
        "conditions": {c.name: {"wall_s_attributed": per_cond[c.name],
                                "trial_steps": int(sum(int(v.sum()) for v in steps[c.name].values()))}
                       for c in conds},
        "jobs": [{k: v for k, v in info.items() if k != "steps"} for info in infos],
    }
    with open(os.path.join(out, "claims.json"), "w") as fh:
        json.dump(evaluation, fh, indent=1)
    timing_path = os.path.join(out, "timing.json")
    previous = _read_json(timing_path)
    if slots_todo == 0 and previous and previous.get("trials_run", 0) > 0 \
            and set(previous.get("conditions", {})) == set(timing["conditions"]):
        # Nothing was computed: keep the timing of the run that computed the results, note the re-plot.
        previous["replot_s"] = total_s
        timing = previous
    with open(timing_path, "w") as fh:
        json.dump(timing, fh, indent=1)
    write_report(os.path.join(out, "REPORT.md"), evaluation, conds, timing, argv or ["reproduce"])
    with open(os.path.join(out, ".gitignore"), "w") as fh:
        fh.write("cache/\n")
    return ReproduceStats(total, slots_todo, done0 - reused, reused + (slots_todo - len(todo)), total_s, infos)
