"""`python -m experiments bench-compare --what live --against DIR`: `services bench` of this checkout and of
another one (e.g. a worktree of an earlier commit), interleaved phase by phase and repeated, printed side by side
with ratios (of the means, of each round, and their median): on a shared, noisy machine only a comparison within
one run means anything."""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from common.config import option

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class LiveCompareConfig:
    """Steps/s of the live system, this checkout against another, interleaved, in one run (the settings of
    `experiments bench-compare --what live`)."""

    against: str = option("", "the other checkout (a git worktree of the commit to compare with)")
    phases: tuple[str, ...] = option(("ingest", "paper"), "bench phases to compare")
    # (`services bench`'s own default: at 3000 steps an `ingest` phase lasts about 1.5 s, and separate
    # invocations of the same code differed by more than their rounds' spread)
    steps: int = option(8000, "actor steps per phase")
    repeats: int = option(2, "rounds (each runs every phase in both checkouts, alternating which goes first)")
    out: str = option("runs/bench-compare", "directory of the runs and compare.json")

    def __post_init__(self):
        if not self.against or not (Path(self.against) / "services" / "bench.py").is_file():
            raise ValueError(f"--against {self.against!r}: not a checkout of this project")


def one(checkout: Path, phase: str, cfg: LiveCompareConfig, out: Path) -> tuple[float | None, bool, float | None]:
    """Run one phase with `checkout`'s own code: its steps/s (None if it did not run), whether it lost nothing, and
    the CPU ms per step of all its services together (after start-up; less hurt by others' load than steps/s)."""
    cmd = [sys.executable, "-m", "services", "bench", "--phases", phase, "--steps", str(cfg.steps), "--out", str(out)]
    done = subprocess.run(
        cmd, cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)}, capture_output=True, text=True
    )
    files = sorted(out.glob("bench-*.json"))
    if not files:
        print(f"  {checkout}: {phase} did not run (exit {done.returncode}): {done.stderr[-400:]}", file=sys.stderr)
        return None, False, None
    res = json.loads(files[-1].read_text())["phases"][phase]
    cpu = res.get("cpu_ms_per_step") or {}
    return (
        res["steps_per_s"],
        bool(res["zero_loss"] and res["exit_code"] == 0),
        round(sum(cpu.values()), 3) if cpu else None,
    )


def print_rounds(title: str, runs: dict[str, dict[str, list]], ratio) -> None:
    """One line per round and phase (other, this, their ratio), then each phase's median ratio over the rounds
    where both ran."""
    print(title)
    print(f"{'round':<7}{'phase':<9}{'other':>10}{'this':>10}{'ratio':>8}")
    for phase, r in runs.items():
        ratios = []
        for k, (o, t) in enumerate(zip(r["other"], r["this"])):
            ratios += [ratio(o, t)] if o and t else []
            print(
                f"{k + 1:<7}{phase:<9}{o if o else 'n/a':>10}{t if t else 'n/a':>10}"
                f"{f'{ratio(o, t):.3f}' if o and t else 'n/a':>8}"
            )
        median = f"{statistics.median(ratios):.3f}" if ratios else "n/a"
        print(f"{phase}: median ratio {median} over {len(ratios)} rounds")


def bench_compare(cfg: LiveCompareConfig) -> int:
    # Absolute: each checkout's bench runs in its own directory and writes where `out` points.
    other, out = Path(cfg.against).resolve(), Path(cfg.out).resolve() / time.strftime("%Y%m%d-%H%M%S")
    rows: dict[str, dict[str, list]] = {p: {"this": [], "other": []} for p in cfg.phases}
    cpu: dict[str, dict[str, list]] = {p: {"this": [], "other": []} for p in cfg.phases}
    for r in range(cfg.repeats):
        for phase in cfg.phases:
            order = [("other", other), ("this", ROOT)] if r % 2 == 0 else [("this", ROOT), ("other", other)]
            for label, checkout in order:
                sps, clean, cpu_ms = one(checkout, phase, cfg, out / f"{label}-{phase}-{r}")
                rows[phase][label].append(sps)
                cpu[phase][label].append(cpu_ms)
                print(
                    f"round {r + 1} {phase:<8} {label:<5} {sps} steps/s, {cpu_ms} CPU ms/step"
                    f"{'' if clean else ' (NOT zero loss / exit != 0)'}",
                    file=sys.stderr,
                    flush=True,
                )
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.json").write_text(
        json.dumps({"against": str(other), "rows": rows, "cpu_ms_per_step": cpu}, indent=2)
    )
    print(
        f"this checkout ({ROOT}) against {other}, {cfg.steps} steps, interleaved "
        f"(load average now {' '.join(f'{x:.2f}' for x in os.getloadavg())}):"
    )
    print_rounds("steps/s; ratio this/other (above 1: this checkout is faster)", rows, lambda o, t: t / o)
    print_rounds(
        "CPU ms per step of all services together; ratio other/this (above 1: this checkout needs less)",
        cpu,
        lambda o, t: o / t,
    )
    missing = [f"{label} {phase}" for phase, r in rows.items() for label, runs in r.items() if None in runs]
    if missing:
        print(
            f"some runs did not run or left no result ({', '.join(missing)}): the ratios above leave them out",
            file=sys.stderr,
        )
    return 1 if missing else 0
