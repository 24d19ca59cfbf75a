"""How well the perception path carried a video-backed observer's reactions: the face-video part of
`summary.json`.

Inputs: the observer's `ObserverReaction`s (what it meant and showed, with the capture times of the first and
last frame of each clip) and the perceived `Feedback` of the same teacher id. A reaction's window runs from
its first frame to its last (the reaction detector fires only on a frame with a face, and the face is gone
between clips) plus `slack_s`; the first feedback in the window is the reaction's reading, any other feedback
in it or outside every window is *extra*. Reported:

- `polarity_error_rate`: read reactions whose perceived value differs from the observer's intended value
  (the headline: what the learner got wrong relative to what the observer meant; includes simulated misreads
  when `--flip` > 0);
- `perception_polarity_error_rate`: the same against the value shown (the perception path alone);
- `missed` / `miss_rate`: reactions shown that produced no feedback; `extra`: feedback that matches no
  reaction (a second firing, or one while no face was shown);
- `lag_s`: first frame of the clip -> capture time of the frame that fired (p10, p50, p90, max).
"""

from __future__ import annotations

import bisect
from typing import Any
from collections.abc import Iterable

import numpy as np

from common.protocol import Feedback, ObserverReaction


def _q(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    a = np.asarray(values, dtype=float)
    return {k: round(float(np.percentile(a, p)), 4) for k, p in (("p10", 10), ("p50", 50), ("p90", 90), ("max", 100))}


def face_metrics(
    reactions: Iterable[ObserverReaction], feedback: Iterable[Feedback], slack_s: float = 0.05
) -> dict[str, Any]:
    """Match perceived feedback to shown reactions by capture time, per teacher id."""
    out: dict[str, Any] = {}
    by_teacher: dict[str, list[ObserverReaction]] = {}
    for r in reactions:
        by_teacher.setdefault(r.teacher_id, []).append(r)
    fb_by_teacher: dict[str, list[Feedback]] = {}
    for f in feedback:
        fb_by_teacher.setdefault(f.teacher_id, []).append(f)
    for tid, rs in sorted(by_teacher.items()):
        rs = sorted({r.seq: r for r in rs}.values(), key=lambda r: r.t_start)  # a re-sent reaction counts once
        fbs = sorted({f.seq: f for f in fb_by_teacher.get(tid, [])}.values(), key=lambda f: f.t_reaction)
        starts = [r.t_start for r in rs]
        first: dict[int, Feedback] = {}
        extra = 0
        for f in fbs:
            i = bisect.bisect_right(starts, f.t_reaction) - 1
            if i >= 0 and f.t_reaction <= rs[i].t_end + slack_s and i not in first:
                first[i] = f
            else:
                extra += 1
        read = len(first)
        wrong_vs_intended = sum(first[i].value != rs[i].intended for i in first)
        wrong_vs_shown = sum(first[i].value != rs[i].value for i in first)
        lags = [first[i].t_reaction - rs[i].t_start for i in sorted(first)]
        out[tid] = {
            "reactions_shown": len(rs),
            "reactions_read": read,
            "missed": len(rs) - read,
            "miss_rate": round((len(rs) - read) / len(rs), 4) if rs else None,
            "extra": extra,
            "feedback_perceived": len(fbs),
            "polarity_errors": wrong_vs_intended,
            "polarity_error_rate": round(wrong_vs_intended / read, 4) if read else None,
            "perception_polarity_errors": wrong_vs_shown,
            "perception_polarity_error_rate": round(wrong_vs_shown / read, 4) if read else None,
            "shown_flipped": sum(r.value != r.intended for r in rs),
            "shown_positive": sum(r.value > 0 for r in rs),
            "lag_s": _q(lags),
        }
    return out
