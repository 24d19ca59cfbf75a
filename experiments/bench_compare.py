"""`python -m experiments bench-compare --against DIR`: `experiments bench` of this checkout and of another one
(e.g. a worktree of an earlier commit), alternating which goes first, round after round, in one run.

Each run is `python -m experiments bench` in its own checkout (its own code first on the path, a fresh process).
Printed per round and mode (plain loop, batched, parallel): both times and the speed ratio in environment steps
per second, this / other (above 1: this checkout is faster; steps per second, not seconds, because the two
checkouts may define the same condition with other layouts or lengths, so the same trials need not take the
same number of steps); last, the median ratio per mode. Pass the same `--conditions` to both where the
checkouts list different ones. On a shared, noisy machine only ratios
taken within one run mean anything; the load average at the start and the end is printed beside them.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODES = ("plain_s", "batched_s", "parallel_s")


def run_bench(checkout: Path, bench_args: list[str]) -> dict:
    """One `experiments bench` run with `checkout`'s own code; its JSON report."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.json"
        cmd = [sys.executable, "-m", "experiments", "bench", *bench_args, "--out", str(out)]
        done = subprocess.run(cmd, cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)},
                              capture_output=True, text=True)
        if done.returncode != 0 or not out.is_file():
            raise RuntimeError(f"{checkout}: bench failed (exit {done.returncode}): {done.stderr[-600:]}")
        return json.loads(out.read_text())


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def bench_compare(against: str, rounds: int, bench_args: list[str]) -> dict:
    """Alternate `rounds` runs of both checkouts; print and return the times and ratios."""
    other = Path(against).resolve()
    if not (other / "experiments" / "bench.py").is_file():
        raise ValueError(f"--against {against!r}: not a checkout of this project")
    print(f"experiments bench: this checkout ({ROOT}) against {other}; bench args {' '.join(bench_args)}; "
          f"load average at start {load()}", flush=True)
    print(f"{'round':<6}{'mode':<12}{'other s':>10}{'this s':>10}{'other steps/s':>15}{'this steps/s':>14}"
          f"{'ratio this/other':>18}", flush=True)
    ratios: dict[str, list[float]] = {m: [] for m in MODES}
    runs = []
    for r in range(rounds):
        order = [("other", other), ("this", ROOT)] if r % 2 == 0 else [("this", ROOT), ("other", other)]
        got = {label: run_bench(checkout, bench_args) for label, checkout in order}
        runs.append(got)
        for m in MODES:
            speed = {k: got[k]["env_steps"] / got[k][m] for k in got}
            ratio = speed["this"] / speed["other"]
            ratios[m].append(ratio)
            print(f"{r + 1:<6}{m[:-2]:<12}{got['other'][m]:>10.2f}{got['this'][m]:>10.2f}{speed['other']:>15.0f}"
                  f"{speed['this']:>14.0f}{ratio:>18.3f}", flush=True)
    medians = {m: statistics.median(v) for m, v in ratios.items()}
    print(f"environment steps per run: other {runs[0]['other']['env_steps']}, this {runs[0]['this']['env_steps']}")
    print("median speed ratio this/other (above 1: this checkout is faster): "
          + ", ".join(f"{m[:-2]} {v:.3f}" for m, v in medians.items()) + f"; load average at end {load()}")
    return {"against": str(other), "bench_args": bench_args, "runs": runs, "ratios": ratios, "medians": medians}
