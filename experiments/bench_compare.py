"""`python -m experiments bench-compare --against DIR [--what inprocess|live]`: the in-process runner (or, with
`--what live`, the live system: services/bench_compare.py) of this checkout against another one
(e.g. a worktree of an earlier commit), alternating which goes first, round after round, in one run.

Each run is a fresh process in its own checkout (its code first on the path) that builds the same trials from
the interfaces every commit has (`TrialSpec` of an environment name, `agent_config(algo)`, the default
`ObserverConfig`, a seed, a maze layout, a length) and runs them with its own `run_trials` two ways, as
`experiments bench` does: plain (each trial alone, one after another) and batched (one lockstep batch per
environment). The maze layouts and agents' defaults may differ between commits, so the trials need not take
the same number of environment steps: the ratio is of environment steps per second, this / other (above 1:
this checkout is faster). A lockstep batch steps all its running trials at once until its longest trial ends,
so its time follows its ticks (the longest trial's steps) more than its steps: the batched mode is also
compared per tick. The parallel mode of `experiments bench` is the batched arithmetic on a process pool
whose interface differs between commits, so it is left out. Printed per round and mode: both times, steps/s,
the ratio, and the ratio of steps per CPU second of the run's process (others' load lengthens wall time far
more than CPU time); last, the median ratios per mode and the load average at the start and the end (on a
shared, noisy machine only ratios taken within one run mean anything).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from common.config import option

ROOT = Path(__file__).resolve().parents[1]
MODES = ("plain_s", "batched_s")

# Run inside the checkout under test: only the interfaces both old and new checkouts have.
_TIMED_RUN = """
import json, sys, time
from common.agents import agent_config
from common.core.observer import ObserverConfig
from experiments.runner import TrialSpec, run_trials
envs, trials, episodes = json.loads(sys.argv[1])
specs = [TrialSpec(env, agent_config(algo), ObserverConfig(), seed=k, layout=k % 10 if env == "maze" else 0,
                   episodes=episodes)
         for env in envs for algo in ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer") for k in range(trials)]
t0, c0 = time.perf_counter(), time.process_time()
plain = [run_trials([s])[0] for s in specs]
t_plain, c_plain = time.perf_counter() - t0, time.process_time() - c0
t0, c0 = time.perf_counter(), time.process_time()
for env in envs:
    run_trials([s for s in specs if s.env == env])
t_batched, c_batched = time.perf_counter() - t0, time.process_time() - c0
# A batch steps all its running trials at once until its longest trial ends: its lockstep ticks.
ticks = sum(max(r.total_steps for r, s in zip(plain, specs) if s.env == env) for env in envs)
print(json.dumps({"trials": len(specs), "env_steps": int(sum(r.total_steps for r in plain)), "ticks": ticks,
                  "plain_s": t_plain,
                  "batched_s": t_batched, "plain_cpu_s": c_plain, "batched_cpu_s": c_batched}))
"""


def timed_run(checkout: Path, envs: list[str], trials: int, episodes: int) -> dict:
    """The trials run plain and batched with `checkout`'s own code: its times and environment steps."""
    arg = json.dumps([envs, trials, episodes])
    done = subprocess.run(
        [sys.executable, "-c", _TIMED_RUN, arg],
        cwd=checkout,
        env={**os.environ, "PYTHONPATH": str(checkout)},
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"{checkout}: the timed run failed (exit {done.returncode}): {done.stderr[-600:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def bench_compare(against: str, rounds: int, envs: list[str], trials: int, episodes: int) -> dict:
    """Alternate `rounds` runs of both checkouts; print and return the times and ratios."""
    other = Path(against).resolve()
    if not (other / "experiments" / "runner.py").is_file():
        raise ValueError(f"--against {against!r}: not a checkout of this project")
    print(
        f"in-process runner: this checkout ({ROOT}) against {other}; environments {' '.join(envs)}, the four "
        f"agents, {trials} trial(s) each, {episodes} episodes; load average at start {load()}",
        flush=True,
    )
    print(
        f"{'round':<6}{'mode':<10}{'other s':>10}{'this s':>10}{'other steps/s':>15}{'this steps/s':>14}"
        f"{'ratio this/other':>18}{'CPU ratio':>12}",
        flush=True,
    )
    ratios: dict[str, list[float]] = {m: [] for m in MODES}
    cpu_ratios: dict[str, list[float]] = {m: [] for m in MODES}  # steps per CPU second: less hurt by others' load
    runs = []
    for r in range(rounds):
        order = [("other", other), ("this", ROOT)] if r % 2 == 0 else [("this", ROOT), ("other", other)]
        got = {label: timed_run(checkout, envs, trials, episodes) for label, checkout in order}
        runs.append(got)
        for m in MODES:
            speed = {k: got[k]["env_steps"] / got[k][m] for k in got}
            ratios[m].append(speed["this"] / speed["other"])
            cpu = {k: got[k]["env_steps"] / got[k][m[:-2] + "_cpu_s"] for k in got}
            cpu_ratios[m].append(cpu["this"] / cpu["other"])
            print(
                f"{r + 1:<6}{m[:-2]:<10}{got['other'][m]:>10.2f}{got['this'][m]:>10.2f}{speed['other']:>15.0f}"
                f"{speed['this']:>14.0f}{ratios[m][-1]:>18.3f}{cpu_ratios[m][-1]:>12.3f}",
                flush=True,
            )
    tick_ratios = [
        (g["this"]["ticks"] / g["this"]["batched_s"]) / (g["other"]["ticks"] / g["other"]["batched_s"]) for g in runs
    ]
    medians = {m: statistics.median(v) for m, v in ratios.items()}
    cpu_medians = {m: statistics.median(v) for m, v in cpu_ratios.items()}
    print(
        f"{runs[0]['this']['trials']} trials a run; environment steps: other {runs[0]['other']['env_steps']}, "
        f"this {runs[0]['this']['env_steps']}"
    )
    print(
        "median ratio this/other, steps/s (above 1: this checkout is faster): "
        + ", ".join(f"{m[:-2]} {v:.3f}" for m, v in medians.items())
        + f"; load average at end {load()}"
    )
    print(
        "median ratio this/other, steps per CPU second of the run's process: "
        + ", ".join(f"{m[:-2]} {v:.3f}" for m, v in cpu_medians.items())
    )
    print(
        f"batched, lockstep ticks per second (a batch's time follows its longest trial, not its steps; ticks: "
        f"other {runs[0]['other']['ticks']}, this {runs[0]['this']['ticks']}): median ratio this/other "
        f"{statistics.median(tick_ratios):.3f} (per round {', '.join(f'{x:.3f}' for x in tick_ratios)})"
    )
    return {
        "tick_ratios": tick_ratios,
        "against": str(other),
        "envs": envs,
        "trials": trials,
        "episodes": episodes,
        "runs": runs,
        "ratios": ratios,
        "medians": medians,
        "cpu_ratios": cpu_ratios,
        "cpu_medians": cpu_medians,
    }


@dataclass(frozen=True)
class BenchCompareConfig:
    """This checkout against another (a worktree of an earlier commit), alternating who goes first, round after
    round, in one run: `--what inprocess` times the in-process runner (plain and batched, the four agents),
    `--what live` the live system's bench phases (steps/s and CPU ms per step of all services)."""

    against: str = option("", "the other checkout's directory")
    what: str = option("inprocess", "what to time", choices=("inprocess", "live"))
    rounds: int | None = option(None, "rounds; each runs both checkouts (default: 3 inprocess, 2 live)")
    envs: tuple[str, ...] = option(("maze", "taxi"), "inprocess: environments", nargs="+")
    trials: int = option(1, "inprocess: trials per agent and environment")
    episodes: int = option(10, "inprocess: episodes per trial")
    phases: tuple[str, ...] = option(("ingest", "paper"), "live: bench phases to compare")
    # (`services bench`'s own default: at 3000 steps an `ingest` phase lasts about 1.5 s, and separate
    # invocations of the same code differed by more than their rounds' spread)
    steps: int = option(8000, "live: actor steps per phase")
    out: str | None = option(
        None,
        "inprocess: also write every run's figures and the ratios to this JSON file; "
        "live: directory of the runs and compare.json (default: runs/bench-compare)",
    )

    def __post_init__(self):
        if min(self.rounds or 1, self.trials, self.episodes, self.steps) < 1:
            raise ValueError("--rounds, --trials, --episodes and --steps must be positive")


def main(cfg: BenchCompareConfig) -> int:
    from common.config import fail

    try:
        if cfg.what == "live":
            from services.bench_compare import LiveCompareConfig, bench_compare as live_compare

            return live_compare(
                LiveCompareConfig(cfg.against, cfg.phases, cfg.steps, cfg.rounds or 2, cfg.out or "runs/bench-compare")
            )
        result = bench_compare(cfg.against, cfg.rounds or 3, list(cfg.envs), cfg.trials, cfg.episodes)
    except (ValueError, RuntimeError) as exc:
        fail(str(exc))
    if cfg.out:
        with open(cfg.out, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0
