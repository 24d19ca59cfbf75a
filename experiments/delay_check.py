"""The closed-loop check of the learned delay (`python -m experiments delay-check`): simulated people of known
delay in seconds teach DQN-TAMER, which learns their delay online while it learns the task from that same
feedback (`common.core.delay_model`), and the learned median is compared with the true one.

The rule, declared here before the runs that decide it (`RULE`): for each person, the learned median at the
first episode end after 200 presses lies within 15% of the person's true median then; for the drifting person
(0.5 s to 2 s over the steps in which 200 presses are expected) within 20%. The people (`PEOPLE`) are declared
here too. (A pilot with a 0.4/0.6 bimodal person put the true median on the edge of the gap between the modes,
where a 0.1 error in the estimated weight of a mode moves the median by a third; the declared person is 0.3/0.7:
docs/notes/2026-11-25-learned-delay.md.)
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from typing import Any

from common.agents.config import agent_for
from common.config import nested, option
from common.core.delay import delay_from_spec
from common.core.observer import ObserverConfig
from common.core.task import Task
from experiments.runner import TrialSpec, run_trials

PRESSES, TOLERANCE, DRIFT_TOLERANCE = 200, 0.15, 0.2
RULE = (
    f"each person: |learned median - true median then| <= {TOLERANCE} * true median at the first episode end "
    f"after {PRESSES} presses (the drifting person: {DRIFT_TOLERANCE})"
)

# name -> (delay_s, late_delay_s): the true delay from a step's onset to the press, in seconds.
PEOPLE = {
    "gamma": ("gamma:4,0,0.25", ""),  # median 0.92 s
    "lognormal": ("lognorm:0.6,0,0.9", ""),  # median 0.90 s, long tail (p90 1.94 s, cut at 6 s)
    "bimodal": ("mix:0.3*norm:0.6,0.08+0.7*norm:1.6,0.15", ""),  # modes 0.6 and 1.6 s, median 1.51 s
    "drifting": ("lognorm:0.3,0,0.5", "lognorm:0.3,0,2"),  # median 0.5 s at the start, 2 s from PRESSES on
}


@dataclass(frozen=True)
class DelayCheckConfig:
    """Recover simulated people's delays (seconds) while the agent learns from their feedback."""

    task: Task = option(
        Task(env="maze"),
        "environment (small: the check must be quick), layout, seed",
        flatten=True,
        exclude=("teacher_rule",),
    )
    people: tuple[str, ...] = option(tuple(PEOPLE), f"which of the declared people ({', '.join(PEOPLE)})")
    episodes: int = option(80, f"episodes of the session (at most; it must hold {PRESSES} presses)")
    p_feedback: float = option(0.6, "probability that a step gets a press")
    step_seconds: float = option(0.5, "seconds per step of the virtual clock (2 steps/s)")
    out: str = option("", "write the results to this JSON file (none: print only)")

    def __post_init__(self):
        object.__setattr__(self, "task", nested(self.task, Task))
        unknown = sorted(set(self.people) - set(PEOPLE))
        if unknown:
            raise ValueError(f"unknown person {unknown[0]!r}; choose from {', '.join(PEOPLE)}")
        if self.episodes < 1 or not 0 < self.p_feedback <= 1 or self.step_seconds <= 0:
            raise ValueError("need episodes >= 1, 0 < p-feedback <= 1 and step-seconds > 0")


def true_median(spec: str) -> float:
    return float(delay_from_spec(spec).ppf(0.5))


def check_person(config: DelayCheckConfig, name: str) -> dict:
    """One person's session: the learned median against the true one, by the declared rule."""
    early, late = PEOPLE[name]
    agent = dataclasses.replace(agent_for("dqn-tamer", None), learn_delay=True)
    observer = ObserverConfig(
        p_feedback=config.p_feedback, delay_s=early, late_delay_s=late, drift_steps=int(PRESSES / config.p_feedback)
    )
    task = config.task
    spec = TrialSpec(
        task.env, agent, observer, task.seed, task.layout, config.episodes, step_seconds=config.step_seconds
    )
    result = run_trials([spec])[0]
    given = steps = 0
    out: dict[str, Any] = {"person": name, "delay_s": early, "late_delay_s": late, "learned_end": result.delay}
    for e in result.episodes:
        given, steps = given + e["feedback_given"], steps + e["steps"]
        if given >= PRESSES:
            break
    else:
        out.update(passed=False, presses=given, why=f"only {given} presses in {config.episodes} episodes")
        return out
    w = min(1.0, steps / observer.drift_steps) if late else 0.0  # (quantiles mix: so do the medians)
    truth = (1 - w) * true_median(early) + w * true_median(late or early)
    tol = DRIFT_TOLERANCE if late else TOLERANCE
    learned = e["delay_median_s"]
    out.update(
        true_median_s=round(truth, 4),
        learned_median_s=round(learned, 4),
        presses=given,
        compared_at=f"episode {e['episode']} ({given} presses, {steps} steps)",
        relative_error=round(abs(learned - truth) / truth, 4),
    )
    out["passed"] = bool(out["relative_error"] <= tol)
    return out


def delay_check(config: DelayCheckConfig) -> list[dict]:
    return [check_person(config, name) for name in config.people]


def main(config: DelayCheckConfig) -> int:
    """Print one line per person; exit 1 if any fails the declared rule."""
    print(f"rule: {RULE}")
    results = delay_check(config)
    for r in results:
        got, truth = r.get("learned_median_s", float("nan")), r.get("true_median_s", float("nan"))
        print(
            f"{r['person']:10s} true median {truth:.3f} s, learned {got:.3f} s "
            f"({r.get('compared_at', r.get('why'))}), error {r.get('relative_error', float('nan')):.1%}: "
            f"{'pass' if r['passed'] else 'FAIL'}"
        )
    if config.out:
        os.makedirs(os.path.dirname(config.out) or ".", exist_ok=True)
        with open(config.out, "w") as fh:
            json.dump({"rule": RULE, "config": dataclasses.asdict(config), "results": results}, fh, indent=1)
    return 0 if all(r["passed"] for r in results) else 1
