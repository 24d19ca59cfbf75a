"""A slice of the reproduction's trials timed in CPU seconds, this checkout against another, side by side.

    python experiments/speed_slice.py --against ../base --rounds 2 maze-high-delay:16:30 taxi-stop:2:6

Each SLICE is CONDITION:TRIALS:EPISODES: TRIALS trials of each of the paper's four agents under the condition's
observer (`experiments.conditions.trial_spec`, layouts from 120 on, seed block 4: the interfaces every commit since
dfd2f6c has), EPISODES episodes each, run as one lockstep batch (`run_trials`), as a reproduction's job runs them.
Printed per slice and checkout: trial-steps, CPU seconds of the process (`time.process_time()`: less hurt by
others' load than wall time), trial-steps per CPU second and a sha256 of the episode records (same hash: same
trajectories). Rounds alternate which checkout goes first; each run is a fresh process with its checkout's code
first on the path. `--profile FILE` instead runs the slices once here under cProfile and writes its stats.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, replace

ALGOS = ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer")
# Run as a file, this folder would come first on the path and its modules shadow others: the checkout's code comes
# from PYTHONPATH instead.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

from common.config import option  # noqa: E402  (after the path is set)


def specs_of(slice_: str) -> list:
    from experiments.conditions import BY_NAME, Scale, trial_spec

    name, trials, episodes = slice_.split(":")
    scale = Scale(layouts=max(int(trials), 2), first_layout=120, seed_block=4)
    cond = BY_NAME[name]
    return [
        replace(trial_spec(cond, algo, k, scale), episodes=int(episodes)) for algo in ALGOS for k in range(int(trials))
    ]


def run_ticks(slice_: str, ticks: str) -> dict:
    """The steady state of one slice's batch: WARM ticks untimed, then TICKS ticks timed (`--ticks WARM:TICKS`)."""
    from experiments import runner

    warm, timed_ticks = (int(t) for t in ticks.split(":"))
    runner.threadpool_limits(1, user_api="blas")
    runner.hold_freed_heap()
    batch = runner._Batch(specs_of(slice_), True, False, False, None, None, None)
    steps, c0 = 0, 0.0
    for k in range(warm + timed_ticks):
        if k == warm:
            c0 = time.process_time()
        steps += int(batch.st["active"].sum()) if k >= warm else 0
        ended = batch.tick()
        if len(ended):
            batch.end_episodes(ended)
    cpu = time.process_time() - c0
    return {
        "slice": slice_,
        "ticks": ticks,
        "trial_steps": steps,
        "cpu_s": round(cpu, 3),
        "sha": "-",
        "steps_per_cpu_s": round(steps / cpu, 1),
        "trials": len(batch.specs),
    }


def run_slice(slice_: str, ticks: str | None = None) -> dict:
    """One slice in this process: its figures (`run_ticks` with ticks)."""
    from experiments.runner import run_trials

    if ticks:
        return run_ticks(slice_, ticks)
    specs = specs_of(slice_)
    c0 = time.process_time()
    results = run_trials(specs)
    cpu = time.process_time() - c0
    fields = ("steps", "return", "feedback_given", "feedback_credited")  # (what every commit records)
    records = json.dumps([[[e[f] for f in fields] for e in r.episodes] for r in results]).encode()
    steps = sum(r.total_steps for r in results)
    return {
        "slice": slice_,
        "trials": len(specs),
        "trial_steps": steps,
        "cpu_s": round(cpu, 3),
        "steps_per_cpu_s": round(steps / cpu, 1),
        "sha": hashlib.sha256(records).hexdigest()[:12],
    }


def timed(checkout: str, slice_: str, ticks: str | None) -> dict:
    done = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--here", "true", slice_] + (["--ticks", ticks] if ticks else []),
        cwd=checkout,
        env={**os.environ, "PYTHONPATH": checkout},
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"{checkout}: {done.stderr[-800:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(this: str, other: str, slices: list[str], rounds: int, ticks: str | None) -> None:
    print(f"this {this} against other {other}; load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"{'round':<6}{'slice':<26}{'who':<6}{'steps':>10}{'CPU s':>9}{'steps/CPU s':>13}{'sha':>14}", flush=True)
    for r in range(rounds):
        for s in slices:
            order = [("other", other), ("this", this)] if r % 2 == 0 else [("this", this), ("other", other)]
            got = {}
            for who, path in order:
                got[who] = g = timed(path, s, ticks)
                print(
                    f"{r + 1:<6}{s:<26}{who:<6}{g['trial_steps']:>10}{g['cpu_s']:>9.2f}{g['steps_per_cpu_s']:>13.0f}"
                    f"{g['sha']:>14}",
                    flush=True,
                )
            ratio = got["this"]["steps_per_cpu_s"] / got["other"]["steps_per_cpu_s"]
            print(f"{'':<6}{s:<26}ratio this/other, steps per CPU s: {ratio:.2f}", flush=True)
    print(f"load average at end {os.getloadavg()[0]:.2f}")


@dataclass(frozen=True)
class SpeedSliceConfig:
    """Slices of the reproduction's trials timed in CPU seconds, this checkout against another, side by side."""

    slices: tuple[str, ...] = option(
        (), "CONDITION:TRIALS:EPISODES (TRIALS per agent)", positional=True, nargs="+", metavar="SLICE"
    )
    against: str = option("", "the other checkout's directory (none: run the slices here)")
    rounds: int = option(2, "rounds; each runs both checkouts, alternating who goes first")
    here: bool = option(False, "run the slices in this process (with PYTHONPATH's code)")
    profile: str = option("", "run the slices here under cProfile, writing its stats to this file")
    ticks: str = option("", "WARM:TICKS: time only ticks WARM+1..WARM+TICKS of each batch (its steady state)")


def main() -> None:
    from common.config import parse_config

    args = parse_config(SpeedSliceConfig, prog="experiments/speed_slice.py")
    ticks = args.ticks or None
    if args.profile:
        import cProfile

        prof = cProfile.Profile()
        out = prof.runcall(lambda: [run_slice(s, ticks) for s in args.slices])
        prof.dump_stats(args.profile)
        print(json.dumps(out))
    elif args.here or not args.against:
        for s in args.slices:
            print(json.dumps(run_slice(s, ticks)), flush=True)
    else:
        this = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        compare(this, os.path.abspath(args.against), list(args.slices), args.rounds, ticks)


if __name__ == "__main__":
    main()
