"""`python -m services.console.measure RUN [RUN ...]`: the console's timing figures, read from runs' logs.

- press -> credited: a person's feedback from its press (system time, `Feedback.t_reaction`) to the learner's H
  update with it (`Credit.t_credited`);
- webcam frame -> face feedback: the capture of the frame that triggered a face feedback (its `t_reaction`)
  to the recorder receiving that Feedback; frame -> expression: capture to the recorder receiving its
  ExpressionPrediction;
- action -> screen: a step's action (`Step.t_action`) to its paint on the person's screen (`Shown.t_shown`);
- steps per feedback: the steps a feedback listed as shown in its window, and those it was credited to.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from common.mcap_read import read_log
from common.protocol import Credit, ExpressionPrediction, Feedback, Shown


def _stats(values: list[float], scale: float = 1e3) -> dict | None:
    if not values:
        return None
    a = np.asarray(values, np.float64) * scale
    return {"n": int(a.size), "p50": round(float(np.percentile(a, 50)), 2), "p99": round(float(np.percentile(a, 99)), 2),
            "mean": round(float(a.mean()), 2), "max": round(float(a.max()), 2)}


def measure(paths: list[str]) -> dict:
    press, face, expression, shown_lag, listed, credited = [], [], [], [], [], []
    for path in paths:
        fbs: dict[tuple[str, int], Feedback] = {}
        for rec in read_log(Path(path)):
            m = rec.message
            if isinstance(m, Feedback) and m.shown is not None:
                fbs[(m.teacher_id, m.seq)] = m
                listed.append(len(m.shown))
                if m.source == "face":
                    face.append(rec.log_time / 1e9 - m.t_reaction)
            elif isinstance(m, Credit) and (m.teacher_id, m.seq) in fbs and m.status == "credited":
                credited.append(sum(1 for s in m.steps if s.weight > 0))
                if fbs[(m.teacher_id, m.seq)].source != "face":
                    press.append(m.t_credited - m.t_reaction)
            elif isinstance(m, Shown):
                shown_lag.append(m.t_shown - m.t_action)
            elif isinstance(m, ExpressionPrediction):
                expression.append(rec.log_time / 1e9 - m.t_capture)
    return {"runs": paths, "press_to_credited_ms": _stats(press), "frame_to_face_feedback_ms": _stats(face),
            "frame_to_expression_ms": _stats(expression), "action_to_screen_ms": _stats(shown_lag),
            "steps_listed_per_feedback": _stats(listed, 1.0), "steps_credited_per_feedback": _stats(credited, 1.0)}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if args else 2
    print(json.dumps(measure([str(Path(a) / "session.mcap") if Path(a).is_dir() else a for a in args]), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
