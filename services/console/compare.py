"""`python -m services.console compare`: does the scripted person at 2 steps/s make DQN-TAMER reach the goal in
fewer episodes than DQN alone?

Each comparison is declared in a data file, `designs/<name>.yaml` (read by `services/console/design.py`), committed
before any of its runs. Each pair is a maze layout with its own seed; in each pair the same scripted person
(`static/scripted_person.js`: the paper's rule, pressing on half the steps it saw, after a lag in seconds from
the paint: uniform 0.3-1.5 s, or a shape the design declares per person, `lags.py`) teaches every arm through the
real console in headless Chromium, one `python -m services.console scripted` process per run, several at once
(the runs are paced by the clock, not the CPU).

Primary measure (per design, `Design.measure`): the episode in which the agent first reached the goal within twice
the shortest path (never = episodes + 1), or, in the fourth design, the episode in which it reached the goal for
the tenth time. Primary test, the only one that decides: DQN's measure minus DQN-TAMER's, one-sided Wilcoxon
signed-rank over the pairs (zero differences dropped), at 0.05 divided by the number of designs tested so far
(`multiplicity: looks`), or one such test per declared person and layout kind with Holm's step-down at 0.05 over
them (`multiplicity: holm`). Secondary, shown and never deciding: the sign test, steps over all episodes, other arms.

Resuming: each finished run is kept under OUT/DESIGN/COMMIT/ and skipped when the command is run again, so a design
can be completed over several stretches; a run is keyed by design, pair (and person), arm and the git commit of the
code. A tree with uncommitted changes is keyed COMMIT-dirty-HASH (a hash of its changes), never as the commit; a
design that names its commit (`commit:`) refuses any other checkout and any dirty tree. Each stretch prints how
many runs are done and how many remain, with an estimate of the time left.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from common.config import option, parse_config
from services.console.design import Arm, Design, checkout_key, load_designs
from services.console.scripted import DEFAULT
from services.console.compare_tests import episodes_to_goal, MEASURE_TITLES, declared_tests, secondary_tests

ROOT = Path(__file__).resolve().parents[2]


DESIGNS = load_designs()


@dataclass(frozen=True)
class CompareConfig:
    """Run a declared comparison (DESIGNS in this module) and write its table, figure and verdict."""

    design: str = option(
        "first",
        "which declared design (services/console/designs/NAME.yaml): "
        + "; ".join(f"{n} ({d.summary})" for n, d in DESIGNS.items()),
        choices=tuple(DESIGNS),
    )
    out: str = option("runs/compare", "directory of the runs and results (each design's under OUT/DESIGN/COMMIT)")
    parallel: int = option(8, "runs at once")
    pairs: int | None = option(None, "only the first N pairs (a trial of the machinery; no verdict is written)")
    timeout: float = option(2400.0, "seconds a run may take")


def _tag(arm: Arm, person: str | None, layout: int, seed: int) -> str:
    credit = "" if arm.screen_credit == "interval" else f"-{arm.screen_credit}"
    who = f"-{person}" if person else ""
    return f"{arm.algo}-{arm.screen_delay.replace(':', '').replace(',', '-')}{credit}{who}-l{layout}-s{seed}"


def scripted_command(
    design: Design, arm: Arm, person: str | None, layout: int, seed: int, base: Path, tag: str, timeout: float
) -> list[str]:
    """The `services.console scripted` process of one run (its result JSON at base/results/TAG.json)."""
    cmd = [
        sys.executable,
        "-m",
        "services.console",
        "scripted",
        "--algo",
        arm.algo,
        "--layout",
        str(layout),
        "--seed",
        str(seed),
        "--episodes",
        str(design.episodes),
        "--rate",
        str(design.rate),
        "--episode-steps",
        str(design.episode_steps),
        "--p",
        str(design.p_press),
        "--good-factor",
        str(design.good_factor),
        "--out",
        str(base / "runs"),
        "--run",
        tag,
        "--timeout",
        str(timeout),
        "--result",
        str(base / "results" / f"{tag}.json"),
    ]
    for flag, value in (("--screen-delay", arm.screen_delay), ("--screen-credit", arm.screen_credit)):
        cmd += [flag, value] if value != DEFAULT else []  # (default: the run's own setting, as preflight checks)
    return cmd + (["--lag", design.people[person]] if person is not None else [])


@dataclass(frozen=True)
class Run:
    """One run of a design: its key is the design, the arm, the person, the pair and the code's commit."""

    arm: Arm
    person: str | None
    layout: int
    seed: int

    @property
    def tag(self) -> str:
        return _tag(self.arm, self.person, self.layout, self.seed)


def run_dir(cfg: CompareConfig, design: Design, key: str) -> Path:
    """Where the runs of `design` made by the code `key` are kept (so that no other code's run is reused)."""
    return Path(cfg.out) / design.name / key


def finished(base: Path, run: Run, key: str) -> dict | None:
    """The record of a finished run of this code (None: not run, or left unfinished by a stopped stretch)."""
    done = base / "results" / f"{run.tag}.done.json"
    if not done.exists():
        return None
    record = json.loads(done.read_text())
    return record if record.get("key") == key else None


def run_arm(cfg: CompareConfig, design: Design, run: Run, key: str) -> dict:
    """One scripted session (its own process), or the kept result of the same run of the same code; its row."""
    base = run_dir(cfg, design, key)
    result = base / "results" / f"{run.tag}.json"
    if finished(base, run, key) is None:
        shutil.rmtree(base / "runs" / run.tag, ignore_errors=True)  # a stopped or failed attempt's: run it again
        result.unlink(missing_ok=True)
        result.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.monotonic()
        cmd = scripted_command(design, run.arm, run.person, run.layout, run.seed, base, run.tag, cfg.timeout)
        with (base / "results" / f"{run.tag}.log").open("w") as log:
            rc = subprocess.run(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, check=False).returncode
        if rc != 0 or not result.exists():
            raise RuntimeError(f"run {run.tag} failed (exit {rc}): see {result.with_suffix('.log')}")
        json.loads(result.read_text())  # a torn result file is no finished run
        done = result.with_suffix(".done.json")
        done.with_suffix(".tmp").write_text(
            json.dumps({"key": key, "design": design.name, "wall_s": round(time.monotonic() - t0, 1)})
        )
        done.with_suffix(".tmp").replace(done)  # the run counts as finished only once this record is whole
    row = json.loads(result.read_text())["runs"][0]
    return {"arm": run.arm.name, "person": run.person, "layout": run.layout, "seed": run.seed, **row}


def cell(row: dict, design: Design) -> str:
    first_good = row["first_good_episode"] or "never"
    if design.measure == "goals":
        return f"{episodes_to_goal(row, design)} ({row['total_steps']} steps; first near-shortest: {first_good})"
    return f"{first_good} ({row['total_steps']} steps)"


def table(rows: list[dict], design: Design) -> str:
    people = design.persons()
    lines = [
        "| "
        + ("person | " if people != [None] else "")
        + "layout | seed | "
        + " | ".join(a.name for a in design.arms)
        + " |",
        "|" + "---|" * (len(design.arms) + 2 + (people != [None])),
    ]
    by = {(r["arm"], r.get("person"), r["layout"], r["seed"]): r for r in rows}
    for person in people:
        for lay, s in design.pairs:
            cells = [cell(by[a.name, person, lay, s], design) for a in design.arms]
            lines.append("| " + (f"{person} | " if person else "") + f"{lay} | {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(rows: list[dict], design: Design, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    people = design.persons()
    fig, axes = plt.subplots(len(people), 2, figsize=(11, 4 * len(people)), squeeze=False)
    title = MEASURE_TITLES[design.measure].format(f=design.good_factor, n=design.episodes + 1, k=design.goals)
    for (left, right), person in zip(axes, people):
        for a in design.arms:
            mine = {(r["layout"], r["seed"]): r for r in rows if r["arm"] == a.name and r.get("person") == person}
            steps = np.array([mine[p]["steps_per_episode"][: design.episodes] for p in design.pairs], float)
            right.plot(np.arange(1, steps.shape[1] + 1), np.median(steps, axis=0), marker="o", label=a.name)
            left.plot(
                [f"{lay}/{s}" for lay, s in design.pairs],
                [episodes_to_goal(mine[p], design) for p in design.pairs],
                marker="o",
                linestyle="none",
                label=a.name,
            )
        who = f"{person}: " if person else ""
        left.set(xlabel="layout/seed", ylabel="episodes (fewer is better)", title=who + title)
        left.tick_params(axis="x", labelrotation=60, labelsize=7)
        right.set(xlabel="episode", ylabel="steps (median over pairs)", yscale="log", title=who + "steps per episode")
        left.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(rows: list[dict], design: Design, out: Path) -> None:
    tests = declared_tests(rows, design)
    figure(rows, design, out / "compare.png")
    secondary = secondary_tests(rows, design)
    (out / "compare.json").write_text(
        json.dumps(
            {"design": asdict(design), "tests": tests, "primary": tests[0], "secondary": secondary, "runs": rows},
            indent=1,
        )
    )
    (out / "compare.md").write_text(table(rows, design) + "\n")
    print(table(rows, design))
    measure = MEASURE_TITLES[design.measure].format(f=design.good_factor, n=design.episodes + 1, k=design.goals)
    for t in tests:
        where = " ".join(x for x in (t["person"], t["kind"]) if x)
        print(
            f"{where + ': ' if where else ''}{design.primary[0]} minus {design.primary[1]}, {measure}: mean "
            f"{t['mean']:+.2f}, {t['wins']} wins / {t['ties']} ties / {t['losses']} losses, Wilcoxon p "
            f"{t['wilcoxon_p']:.4f} (decides at {t['alpha']:.4f}, {design.multiplicity}), sign p "
            f"{t['sign_p']:.4f}: {t['verdict']}"
        )
    for t in secondary:
        print(
            f"  secondary (never deciding), {t['person']} on {t['kind']} layouts: mean {t['mean']:+.2f}, "
            f"{t['wins']}/{t['ties']}/{t['losses']}, Wilcoxon p {t['wilcoxon_p']:.4f}"
        )
    for a in design.arms:
        print(f"  {a.name}: {sum(r['total_steps'] for r in rows if r['arm'] == a.name)} steps in all")
    print(f"wrote {out / 'compare.json'}, compare.md, compare.png")


def preflight(design: Design) -> str | None:
    """Why this checkout cannot run the design's arms (each arm's settings as `services up` would take them), or
    None: checked before any run starts, so that a design never runs half."""
    from services.common.config import LearnerConfig
    from services.console.config import ConsoleConfig
    from services.launcher.config import UpConfig

    for arm in design.arms:
        flags = ["--teacher", "web", "--algo", arm.algo]
        for flag, value in (("--screen-delay", arm.screen_delay), ("--screen-credit", arm.screen_credit)):
            flags += [flag, value] if value != DEFAULT else []
        try:
            up = parse_config(UpConfig, flags)  # and what the launcher makes of it for the learner and the console
            LearnerConfig(run="preflight", algo=arm.algo, screen_delay=up.screen_delay, screen_credit=up.screen_credit)
            ConsoleConfig(run="preflight", algo=arm.algo, learner=up.learner)
        except (SystemExit, ValueError) as exc:
            return f"arm {arm.name!r} ({' '.join(flags)}): {exc}"
    return None


def time_left(walls: list[float], remaining: int, parallel: int, design: Design) -> str:
    """The time the remaining runs should take: the median finished run (before any, the longest a run can be:
    every episode cut at its step limit) times the rounds of `parallel` runs they need."""
    per_run = float(np.median(walls)) if walls else design.episodes * design.episode_steps / design.rate
    seconds = per_run * -(-remaining // max(parallel, 1))
    basis = f"median run {per_run:.0f} s" if walls else f"no run finished yet: at most {per_run:.0f} s a run"
    return f"about {seconds / 3600:.1f} h left ({basis}, {parallel} at once)"


def run_design(cfg: CompareConfig, design: Design, root: Path = ROOT) -> int:
    """Run every run of `design` not yet finished by this code, keeping each as it finishes (a stopped stretch
    loses only the runs in flight); then, with every run done, its table, figure and verdict."""
    try:
        key = checkout_key(design, root)
    except ValueError as exc:
        print(f"[compare] refused: {exc}", file=sys.stderr)
        return 2
    from tqdm import tqdm

    base = run_dir(cfg, design, key)
    pairs = design.pairs[: cfg.pairs] if cfg.pairs else design.pairs
    runs = [Run(a, who, lay, s) for who in design.persons() for lay, s in pairs for a in design.arms]
    kept = {run: finished(base, run, key) for run in runs}
    walls = [r["wall_s"] for r in kept.values() if r]
    print(
        f"[compare] design {design.name} on {key}: {len(walls)} of {len(runs)} runs done, {len(runs) - len(walls)}"
        f" remain, {time_left(walls, len(runs) - len(walls), cfg.parallel, design)}; kept in {base}",
        file=sys.stderr,
        flush=True,
    )
    results: dict[Run, dict] = {}
    failed: list[str] = []
    with (
        tqdm(total=len(runs), initial=len(walls), desc=design.name, unit="run", file=sys.stderr) as bar,
        ThreadPoolExecutor(cfg.parallel) as pool,
    ):
        futures = {pool.submit(run_arm, cfg, design, run, key): run for run in runs}
        for future in as_completed(futures):
            run = futures[future]
            try:
                results[run] = future.result()
            except RuntimeError as exc:  # the others go on, and stay kept
                failed.append(str(exc))
                continue
            if kept[run] is None:  # made in this stretch
                walls.append((finished(base, run, key) or {"wall_s": 0.0})["wall_s"])
                bar.update(1)
                bar.set_postfix_str(time_left(walls, len(runs) - bar.n, cfg.parallel, design))
    if failed:
        print(
            "[compare] " + "\n[compare] ".join(failed) + f"\n[compare] {len(failed)} runs failed; the "
            f"{len(results)} others are kept: run the same command again to retry",
            file=sys.stderr,
        )
        return 1
    rows = [results[run] for run in runs]
    if cfg.pairs:
        print(json.dumps(rows, indent=1))
        return 0
    report(rows, design, base)
    return 0


def main(cfg: CompareConfig) -> int:
    design = DESIGNS[cfg.design]
    refused = preflight(design)
    if refused:
        print(f"[compare] design {design.name} cannot run here: {refused}", file=sys.stderr)
        return 2
    return run_design(cfg, design)


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(CompareConfig, argv, prog="python -m services.console compare"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services.console compare")
