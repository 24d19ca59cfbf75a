"""`python -m services.console people --design NAME`: the people's side of a comparison's runs, checked.

A comparison is only as good as its scripted people: a page that could not see the board, or a person whose presses
never arrived, would make DQN-TAMER look like DQN. For each finished run of the design (kept by `compare` under
OUT/DESIGN/COMMIT/), this reads the run's summary and reports:

- the pace it held: steps per second of the run's wall time, against the design's rate (episode resets and the
  start take a little of it, so about 0.9 of the rate is normal; a dozen runs that slowed one another show less);
- the person's presses per step: what the console received from the page, against the design's `p_press` (the
  person presses on that share of the steps they saw);
- every run whose person pressed at less than half the design's rate, or whose pace fell below 3/4 of it, with
  what the run's summary says about why (no steps shown, presses dropped on the way, a run that did not finish).

It writes `people.json` beside the runs and prints a table; it never changes a kept run or a verdict.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from common.config import option
from services.console.design import Design, load_designs

LOW_PRESSES = 0.5  # of the design's p_press: a person pressing less than this share is reported
LOW_PACE = 0.75  # of the design's rate: a run slower than this is reported


@dataclass(frozen=True)
class PeopleConfig:
    """Check the pace and the people's presses of a comparison's finished runs."""

    design: str = option(
        "unknown-teacher", "which declared design (services/console/designs/NAME.yaml)", choices=tuple(load_designs())
    )
    out: str = option("runs/compare", "the directory compare kept its runs in (its --out)")
    commit: str | None = option(None, "the runs of this code key (default: the design's commit, or the only one kept)")


def run_check(summary: dict, design: Design) -> dict:
    """One run's pace and presses, and why they are low where they are."""
    steps = int(summary.get("steps_sent") or 0)
    wall = float(summary.get("wall_s") or 0.0)
    person: dict = next(iter((summary.get("people") or {}).values()), {})
    presses = int(person.get("received", 0))
    pace = steps / wall if wall > 0 else 0.0
    rate = presses / steps if steps else 0.0
    why = []
    if summary.get("outcome") != "ok":
        why.append(f"outcome {summary.get('outcome')}")
    if steps == 0:
        why.append("no step was taken")
    lost = int(person.get("published", presses)) - int(person.get("logged", presses))
    if lost > 0:
        why.append(f"{lost} presses published and not logged")
    if rate < LOW_PRESSES * design.p_press and not why:
        why.append("the page pressed little (see the run's logs/console log and the scripted person's plan)")
    low = rate < LOW_PRESSES * design.p_press or pace < LOW_PACE * design.rate
    return {
        "steps": steps,
        "wall_s": wall,
        "pace": round(pace, 3),
        "presses": presses,
        "presses_per_step": round(rate, 3),
        "reported": low,
        "why": why if low else [],
    }


def kept_key(base: Path, design: Design, commit: str | None) -> Path:
    keys = sorted(p for p in (base / design.name).iterdir() if p.is_dir()) if (base / design.name).exists() else []
    wanted = commit or (design.commit if len(keys) != 1 else keys[0].name)
    for key in keys:
        if key.name == wanted or key.name.startswith(wanted):
            return key
    raise ValueError(f"no kept runs of {design.name} for {wanted!r} under {base / design.name} (kept: {keys})")


def main(cfg: PeopleConfig) -> int:
    design = load_designs()[cfg.design]
    try:
        key = kept_key(Path(cfg.out), design, cfg.commit)
    except ValueError as exc:
        print(f"[people] {exc}", file=sys.stderr)
        return 2
    rows = {}
    for done in sorted((key / "results").glob("*.done.json")):
        tag = done.name.removesuffix(".done.json")
        summary = key / "runs" / tag / "summary.json"
        if summary.exists():
            rows[tag] = run_check(json.loads(summary.read_text()), design)
    paces = sorted(r["pace"] for r in rows.values())
    reported = {t: r for t, r in rows.items() if r["reported"]}
    (key / "people.json").write_text(json.dumps({"design": design.name, "runs": rows}, indent=1))
    print(
        f"{len(rows)} finished runs of {design.name} ({key.name[:12]}); design rate {design.rate} steps/s, "
        f"p_press {design.p_press}"
    )
    if paces:
        print(
            f"pace held: median {paces[len(paces) // 2]:.2f} steps/s, slowest {paces[0]:.2f}, fastest {paces[-1]:.2f}"
        )
    for tag, r in reported.items():
        print(f"  reported: {tag}: {r['pace']} steps/s, {r['presses_per_step']} presses a step; {'; '.join(r['why'])}")
    print(f"{len(reported)} runs reported; wrote {key / 'people.json'}")
    return 0
