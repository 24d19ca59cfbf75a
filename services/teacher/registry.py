"""Teacher kinds the launcher can start (`python -m services up --teacher NAME`).

A kind says which processes make up the teacher, given the launch settings. `oracle` is the simulated
observer (`python -m services.teacher`). Another kind (e.g. `face-video`: a camera or video source, the
perception service and a face-reading teacher) registers itself here with `register(...)`; the launcher
only needs the processes' argv and service names.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable


@dataclasses.dataclass(frozen=True)
class ProcessSpec:
    """One process to start: its service name (liveliness token / status key), module and config."""

    name: str
    module: str  # run as `python -m <module> --config <file>`
    config: Any  # a config dataclass instance (written to a JSON file by the launcher)


@dataclasses.dataclass(frozen=True)
class TeacherKind:
    name: str
    doc: str
    # (launch settings, teacher id) -> the processes that make this teacher; the first one's name is the
    # teacher's service name (the learner waits for its final count of feedback).
    build: Callable[[Any, str], list[ProcessSpec]]
    available: Callable[[], str | None] = lambda: None  # None if usable, else why not


TEACHERS: dict[str, TeacherKind] = {}


def register(kind: TeacherKind) -> None:
    TEACHERS[kind.name] = kind


def teacher_names() -> tuple[str, ...]:
    return tuple(TEACHERS)


def _oracle(up: Any, teacher_id: str) -> list[ProcessSpec]:
    from services.common.config import TeacherConfig, teacher_service_name

    cfg = TeacherConfig(run=up.run, connect=up.connect_endpoints, parent_pid=up.parent_pid,
                        stats_out=up.stats_path(teacher_service_name(teacher_id)), env=up.env, layout=up.layout,
                        seed=up.seed, teacher_id=teacher_id, p_feedback=up.p_feedback, delay_probs=up.delay_probs,
                        flip=up.flip, stop_episode=up.stop_episode, stop_step=up.stop_step,
                        clock="wall" if up.rate > 0 else "steps",
                        step_unit=1.0 / up.rate if up.rate > 0 else 0.1)
    return [ProcessSpec(teacher_service_name(teacher_id), "services.teacher", cfg)]


register(TeacherKind("oracle", "simulated observer (the core's SimulatedObserver) reacting to the steps it sees",
                     _oracle))


def _face_video_unavailable() -> str | None:
    return "the face-video teacher is not installed yet (a later issue registers it here)"


register(TeacherKind("face-video", "a face on video read by the perception service (not yet available)",
                     lambda up, tid: [], _face_video_unavailable))
