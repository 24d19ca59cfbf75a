"""How the launcher sets up a `face-video` teacher: its processes, its defaults, the delay the learner assumes.

`python -m services up --teacher face-video` starts two processes for one teacher: the video-backed
observer (`services/teacher/face_video.py`, which shows the simulated observer's reactions as clips of a
real face) and the perception service that reads them (`services/perception/`). Feedback that comes through
a face arrives later than the observer's own lag, by the perception path's lag: the learner's assumed delay
is shifted to match (`face_assumed_delay`).
"""

from __future__ import annotations

import math
from typing import Any

from common.protocol import observer_service_name, teacher_service_name

# Where the perception path's lag comes from (measured by `python -m services.teacher face-video measure`,
# docs/perception.md): from the first frame of a clip to the frame that fires, 0.29 s (7 frames at 23.98 fps)
# for most clips, 0.46 s at the 90th percentile of the sad clips.
PERCEPTION_LAG_S = (0.29, 0.46)
DEFAULT_RATE = 3.0  # actor steps per second when --teacher face-video is given no --rate


def face_assumed_delay(
    rate: float, lag_s: tuple[float, float] = PERCEPTION_LAG_S, true_lags: int = 3
) -> tuple[float, ...]:
    """The learner's assumed delay (over 0, 1, 2, ... steps) for feedback that comes through the face.

    The observer reacts to step k at t_k + (d + 0.5) steps (d in 0..true_lags-1) and perception fires
    lag_s later, i.e. (d + 0.5 + lag * rate) steps after action k. The credit rule gives lag i to step
    floor(t_f - i), so step k is credited when some assumed lag i equals floor(d + 0.5 + lag * rate): a
    uniform assumption over floor(0.5 + lag_min * rate) .. floor(true_lags - 0.5 + lag_max * rate) covers
    every case. At 3 steps/s: lags 1..3 (the paper's 0..2 shifted by one step)."""
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be positive, got {rate}")
    lo = int(math.floor(0.5 + lag_s[0] * rate))
    hi = max(lo, int(math.floor(true_lags - 0.5 + lag_s[1] * rate)))
    n = hi - lo + 1
    probs = [0.0] * lo + [round(1.0 / n, 4)] * n
    probs[-1] = round(1.0 - sum(probs[:-1]), 4)
    return tuple(probs)


FACE_END_GRACE = 8.0  # s the learner waits for the perception service after the last step


def face_video_defaults(up) -> dict:
    """What `python -m services up --teacher face-video` changes in the settings the user left at their default:

    - `--rate 0` (as fast as possible) becomes DEFAULT_RATE (3) steps/s: a face needs real time;
    - the learner's assumed delay becomes `face_assumed_delay(rate)` (the paper's uniform 0..2 steps shifted by
      the perception lag: 1..3 steps at 3 steps/s);
    - the teacher id `oracle` becomes `face`; the learner's end grace is at least FACE_END_GRACE s.
    """
    import dataclasses as dc

    fields: dict[str, Any] = {f.name: f.default for f in dc.fields(type(up))}
    out: dict = {}
    rate = up.rate if up.rate > 0 else DEFAULT_RATE
    if up.rate <= 0:
        out["rate"] = rate
    from common.agents.config import agent_for

    if tuple(up.agent.assumed_delay_probs) == tuple(agent_for(up.algo, None).assumed_delay_probs):
        out["assumed_delay_probs"] = face_assumed_delay(rate)
    if up.teacher_id == fields["teacher_id"]:
        out["teacher_id"] = "face"
    if up.end_grace < FACE_END_GRACE:
        out["end_grace"] = FACE_END_GRACE
    return out


def face_video_processes(up, teacher_id: str) -> list[tuple[str, str, object]]:
    """(service name, module, config) of the perception service (the teacher the learner hears, first) and of
    this observer, for the launcher (`services/teacher/registry.py`)."""
    from services.perception.config import PerceptionLiveConfig
    from services.teacher.face_video import FaceVideoConfig

    observer = observer_service_name(teacher_id)
    teacher = teacher_service_name(teacher_id)
    common = dict(run=up.run, connect=up.connect_endpoints, parent_pid=up.parent_pid)
    perception = PerceptionLiveConfig(
        **common,
        stats_out=up.stats_path(teacher),
        source=f"zenoh:{teacher_id}",
        teacher_id=teacher_id,
        stop_with=(observer,),
    )
    o = up.observer
    face = FaceVideoConfig(
        **common,
        stats_out=up.stats_path(observer),
        task=up.task,
        teacher_id=teacher_id,
        camera=teacher_id,
        p_feedback=o.p_feedback,
        delay_probs=o.delay_probs,
        flip=o.p_flip,
        stop_episode=o.stop_episode,
        stop_step=o.stop_step,
        step_unit=1.0 / up.rate,
    )
    return [(teacher, "services.perception", perception), (observer, "services.teacher face-video", face)]
