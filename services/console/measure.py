"""`python -m services.console measure RUN[,RUN ...]`: the console's timing figures, read from runs' logs.

- press -> credited: a person's feedback from its press (system time, `Feedback.t_reaction`) to the learner's H
  update with it (`Credit.t_credited`);
- press -> first action that used it: from the press (`Credit.t_reaction`) to the action (`Step.t_action`) of the
  first step whose weights revision covers the press's H update (`Step.weights_revision >= Credit.revision`),
  for every teacher's credited feedback (a simulated teacher's Credits ride in Ingest); with it, credited ->
  that action, and how many actions came between the credit and it (0: the very next action used it);
- webcam frame -> face feedback: the capture of the frame that triggered a face feedback (its `t_reaction`)
  to the recorder receiving that Feedback; frame -> expression: capture to the recorder receiving its
  ExpressionPrediction;
- action -> screen: a step's action (`Step.t_action`) to its paint on the person's screen (`Shown.t_shown`);
- steps per feedback: the steps a feedback listed as shown in its window, and those it was credited to;
- the share of each press's credit on steps the paper's rule rates as the press does (a scripted person's).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.config import option, parse_config
from common.logs.mcap_read import NotMcapError, read_log
from common.protocol import Credit, ExpressionPrediction, Feedback, Ingest, Shown, Step


def _stats(values: Sequence[float], scale: float = 1e3) -> dict | None:
    if not values:
        return None
    a = np.asarray(values, np.float64) * scale
    return {
        "n": int(a.size),
        "p50": round(float(np.percentile(a, 50)), 2),
        "p99": round(float(np.percentile(a, 99)), 2),
        "mean": round(float(a.mean()), 2),
        "max": round(float(a.max()), 2),
    }


def measure(paths: list[str]) -> dict:
    press, face, expression, shown_lag, listed, credited, agreeing = [], [], [], [], [], [], []
    used = FirstUse()
    for path in paths:
        used.new_log()
        fbs: dict[tuple[str, int], Feedback] = {}
        infos: dict[tuple[str, int], dict] = {}
        for rec in read_log(Path(path)):
            m = rec.message
            used.add(m)
            if isinstance(m, Feedback) and m.shown is not None:
                fbs[(m.teacher_id, m.seq)] = m
                listed.append(len(m.shown))
                if m.source == "face":
                    face.append(rec.log_time / 1e9 - m.t_reaction)
            elif isinstance(m, Credit) and (m.teacher_id, m.seq) in fbs and m.status == "credited":
                credited.append(sum(1 for s in m.steps if s.weight > 0))
                if fbs[(m.teacher_id, m.seq)].source != "face":
                    press.append(m.t_credited - m.t_reaction)
                    share = rule_agreement(m, infos)
                    if share is not None:
                        agreeing.append(share)
            elif isinstance(m, Step):
                infos[(m.incarnation, m.seq)] = m.info
            elif isinstance(m, Shown):
                shown_lag.append(m.t_shown - m.t_action)
            elif isinstance(m, ExpressionPrediction):
                expression.append(rec.log_time / 1e9 - m.t_capture)
    return {
        "runs": paths,
        "press_to_credited_ms": _stats(press),
        **used.figures(),
        "frame_to_face_feedback_ms": _stats(face),
        "frame_to_expression_ms": _stats(expression),
        "action_to_screen_ms": _stats(shown_lag),
        "steps_listed_per_feedback": _stats(listed, 1.0),
        "steps_credited_per_feedback": _stats(credited, 1.0),
        "credit_share_on_steps_the_rule_rates_alike": _stats(agreeing, 1.0),
    }


class FirstUse:
    """Per credited feedback with a revision, the first step whose weights covered it: the steps of its actor
    (in order) are searched for the first action after the credit with `weights_revision >= Credit.revision`."""

    def __init__(self):
        self.credits: list[Credit] = []
        self.steps: dict[str, list[Step]] = {}
        self.pairs: list[tuple[Credit, Step, int]] = []  # (credit, first step using it, actions before it)
        self.unused = 0  # credited with a revision, but no later step used it (the run ended first)

    def add(self, m) -> None:
        if isinstance(m, Step):
            self.steps.setdefault(m.incarnation, []).append(m)
        elif isinstance(m, Credit):
            self.credits.append(m)
        elif isinstance(m, Ingest):
            self.credits.extend(m.credits or ())

    def new_log(self) -> None:
        """Match what the previous log held (each log its own actors and learner)."""
        in_order = {a: sorted(steps, key=lambda s: s.seq) for a, steps in self.steps.items()}
        times = {a: np.array([s.t_action for s in steps], np.float64) for a, steps in in_order.items()}
        for c in self.credits:
            if c.status == "credited" and c.revision is not None and c.actor in in_order:
                self._match(c, in_order[c.actor], times[c.actor])
        self.credits, self.steps = [], {}

    def _match(self, c: Credit, steps: list[Step], t: np.ndarray) -> None:
        after = int(np.searchsorted(t, c.t_credited, side="right"))  # the first action after the H update
        for i in range(after, len(steps)):
            revision = steps[i].weights_revision
            if revision is not None and c.revision is not None and revision >= c.revision:
                self.pairs.append((c, steps[i], i - after))
                return
        self.unused += 1

    def figures(self) -> dict:
        self.new_log()
        return {
            "press_to_first_action_using_it_ms": _stats([s.t_action - c.t_reaction for c, s, _ in self.pairs]),
            "credited_to_first_action_using_it_ms": _stats([s.t_action - c.t_credited for c, s, _ in self.pairs]),
            "actions_between_credit_and_first_use": _stats([float(n) for _, _, n in self.pairs], 1.0),
            "credited_never_used": self.unused,
        }


def rule_agreement(credit: Credit, infos: dict) -> float | None:
    """The share of a press's credit on steps that the paper's rule rates as the press does (a scripted person
    presses by that rule, so a perfect credit scores 1); None where a step's info has no target distances."""
    from common.envs.rules import progress_rule

    rows = [(s.weight, infos.get((credit.actor, s.seq))) for s in credit.steps if s.weight > 0]
    if not rows or any(i is None or "target_distance_after" not in i for _, i in rows):
        return None
    total = sum(w for w, _ in rows)
    return sum(w for w, i in rows if i is not None and progress_rule(i) == credit.value) / total


@dataclass(frozen=True)
class MeasureConfig:
    """The console's timing figures, read from runs' logs."""

    runs: tuple[str, ...] = option((), "run directories (or their session.mcap), comma-separated", positional=True)

    def __post_init__(self):
        if not self.runs:
            raise ValueError("name at least one run directory or session.mcap")
        missing = [r for r in self.logs if not Path(r).is_file()]
        if missing:
            raise ValueError(f"no log at {', '.join(missing)}")

    @property
    def logs(self) -> list[str]:
        return [str(Path(r) / "session.mcap") if Path(r).is_dir() else r for r in self.runs]


def main(cfg: MeasureConfig) -> int:
    try:
        print(json.dumps(measure(cfg.logs), indent=2))
    except NotMcapError as exc:
        print(f"services.console.measure: {exc}", file=sys.stderr)
        return 2
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(MeasureConfig, argv, prog="python -m services.console measure"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services.console measure")
