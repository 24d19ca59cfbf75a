"""`python -m experiments sweep-bench`: one sweep on the local process pool and through a local Ray head,
side by side in one run, and the overhead of a Ray task.

The sweep (default: agent.algo=dqn,dqn-tamer, 30 trials each, the maze's 60 episodes) runs from an
empty cache each time, first on `--workers` local processes, then through a private Ray head on
127.0.0.1 with the same number of CPUs (`ray_head.local_head`), alternating for `--repeats` rounds; the
results must be identical. Overhead per Ray task: (Ray wall - local wall) / Ray tasks of the sweep, and
the round trip of a no-op streaming task (the same kind the sweep submits) measured alone.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from dataclasses import dataclass

from common.config import fail, option
from experiments.sweeps.grid import Sweep, parse_assignment, parse_values
from experiments.sweeps.ray_head import local_head
from experiments.sweeps.report import run_sweep


def _noop():
    yield ("job", {})


def task_round_trip(address: str, n: int) -> dict:
    """Seconds per no-op Ray streaming task, submitted one after another (first one apart: it starts a worker)."""
    from experiments.sweeps.ray_backend import connect

    ray = connect(address)
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_noop).options(num_returns="streaming")
        times = []
        for _ in range(n + 1):
            t0 = time.perf_counter()
            for ref in task.remote():
                ray.get(ref)
            times.append(time.perf_counter() - t0)
        return {"first_s": times[0], "median_s": statistics.median(times[1:]), "n": n}
    finally:
        ray.shutdown()


def bench(sweep: Sweep, workers: int, repeats: int, noop_tasks: int) -> dict:
    rounds = []
    with local_head(num_cpus=workers) as head, tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            row = {}
            for name, ray in (("local", None), ("ray", head.address)):
                out = os.path.join(tmp, f"{name}{r}")
                res = run_sweep(sweep, out, workers=workers, ray=ray, progress=False, n_boot=200)
                jobs = res.run.jobs
                row[name] = {
                    "run_s": res.run.run_s,
                    "total_s": res.total_s,
                    "tasks": len(jobs),
                    "trials": res.run.computed,
                    "job_cpu_s": sum(j["cpu_s"] for j in jobs),
                    "job_wall_max_s": max(j["wall_s"] for j in jobs),
                    "load_after": os.getloadavg()[0],
                }
                with open(os.path.join(out, "trials.csv")) as fh:
                    row[name]["table"] = fh.read()
            row["identical"] = row["local"].pop("table") == row["ray"].pop("table")
            row["overhead_per_task_s"] = (row["ray"]["run_s"] - row["local"]["run_s"]) / max(row["ray"]["tasks"], 1)
            rounds.append(row)
        noop = task_round_trip(head.address, noop_tasks)
    return {
        "cells": len(sweep.cells()),
        "trials_per_cell": sweep.trials,
        "workers": workers,
        "cpus": os.cpu_count(),
        "load_average_at_end": list(os.getloadavg()),
        "rounds": rounds,
        "noop_task": noop,
        "processes_left": head.left,
    }


def format_report(rep: dict) -> str:
    lines = [
        f"sweep: {rep['cells']} cells x {rep['trials_per_cell']} trials, {rep['workers']} workers / Ray CPUs "
        f"(machine: {rep['cpus']} cores, load {rep['load_average_at_end'][0]:.1f} at the end)"
    ]
    for i, r in enumerate(rep["rounds"]):
        lo, ra = r["local"], r["ray"]
        lines.append(
            f"  round {i + 1}: local pool {lo['run_s']:.1f} s ({lo['tasks']} jobs) | Ray head "
            f"{ra['run_s']:.1f} s ({ra['tasks']} tasks) | ratio {ra['run_s'] / lo['run_s']:.2f} | "
            f"overhead per Ray task {r['overhead_per_task_s']:+.2f} s | identical: {r['identical']}"
        )
        lines.append(
            f"           CPU s in the jobs: local {lo['job_cpu_s']:.1f}, Ray {ra['job_cpu_s']:.1f}; "
            "start-up and "
            f"collection (wall - longest job): local {lo['run_s'] - lo['job_wall_max_s']:.1f} s, Ray "
            f"{ra['run_s'] - ra['job_wall_max_s']:.1f} s; load after: {lo['load_after']:.1f}, "
            f"{ra['load_after']:.1f}"
        )
    n = rep["noop_task"]
    lines.append(
        f"  no-op Ray task round trip: first {n['first_s']:.2f} s (starts a worker), then median "
        f"{n['median_s'] * 1000:.1f} ms over {n['n']}"
    )
    lines.append(f"  Ray processes left after stopping the head: {len(rep['processes_left'])}")
    return "\n".join(lines)


@dataclass(frozen=True)
class SweepBenchConfig:
    """One sweep on the local process pool and through a local Ray head, timed side by side: the same numbers
    either way, seconds, Ray's start and per-task overhead, processes left behind."""

    grid: tuple[str, ...] = option(("agent.algo=dqn,dqn-tamer",), "swept fields", nargs="+", metavar="FIELD=V1,V2")
    trials: int = option(30, "trials per cell")
    workers: int = option(2, "local processes and Ray CPUs")
    repeats: int = option(1, "rounds of (local, Ray)")
    noop_tasks: int = option(20, "no-op tasks timed")
    json: str | None = option(None, "also write the numbers to this file")


def main(args: SweepBenchConfig) -> int:
    try:
        grid = {path: parse_values(path, rhs) for path, rhs in map(parse_assignment, args.grid)}
        sweep = Sweep(name="bench", grid=grid, trials=args.trials)
    except ValueError as exc:
        fail(str(exc))
    rep = bench(sweep, args.workers, args.repeats, args.noop_tasks)
    print(format_report(rep))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rep, fh, indent=1)
    return 0 if all(r["identical"] for r in rep["rounds"]) and not rep["processes_left"] else 1


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments sweep-bench")
