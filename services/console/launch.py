"""How `python -m services up --teacher web` starts the console (and, with `--webcam`, the perception
service that reads the people's webcams), for the launcher's teacher registry."""

from __future__ import annotations

from pathlib import Path
from typing import Any

WEBCAM = "webcam"  # camera id of the people's webcam frames


def console_defaults(up: Any) -> dict:
    """A person watches: pace 2 steps/s unless the user chose one, and time for the last presses to land."""
    from common.envs.scene import static_scene

    out: dict[str, Any] = {}
    if static_scene(up.env, up.layout) is None:  # no drawing of ours: show the env's own picture
        out["render_frames"] = True
    if up.idle_updates == 0:  # at a person's pace the learner has time to spare between steps
        out["idle_updates"] = 8
    if up.rate == 0:
        out["rate"] = 2.0
    if up.end_grace == 3.0:
        out["end_grace"] = 6.0
    return out


def console_processes(up: Any, teacher_id: str) -> list[tuple[str, str, object]]:
    from services.common.config import ActorSettings, LearnerSettings
    from services.console.config import ConsoleConfig
    from services.launcher.config import settings

    host = up.host if up.security else "127.0.0.1"
    prefix = "web" if teacher_id == "oracle" else teacher_id  # the launcher's default id is the oracle's
    common = dict(run=up.run, connect=up.connect_endpoints, parent_pid=up.parent_pid)
    from services.console.door import Keys, console_address, read_or_make_token

    token_file = up.state_path(f"teacher.{prefix}", ".token")  # kept by a restarted console: open pages go on
    port_file = up.state_path(f"teacher.{prefix}", ".port")  # (so is its port; a new launcher's console binds anew)
    Path(port_file).unlink(missing_ok=True)
    console = ConsoleConfig(
        **common,
        stats_out=up.stats_path(f"teacher.{prefix}"),
        task=up.task,
        algo=up.algo,
        agent=up.agent,
        **settings(up.console),  # (port 0: the console binds a free one and writes it to port_file)
        host=host,
        teacher_prefix=prefix,
        actor=ActorSettings(rate=up.rate, episodes=up.episodes, start_paused=up.start_paused),
        learner=LearnerSettings(screen_delay=up.screen_delay),
        camera=WEBCAM if up.webcam else None,
        token_file=token_file,
        port_file=port_file,
    )
    scheme = "https" if up.security else "http"  # with --security the console serves HTTPS (router certificate)
    waits = " (the run starts when the first page opens)" if up.start_paused else ""
    # a one-use entry key of the run's secret (services/console/door.py): printed to the person's terminal only
    entry = Keys(read_or_make_token(token_file)).entry()
    # printed once the console listens (the launcher reads its port, then watches it): opens at the first click
    line = lambda bound: f"console: {console_address(scheme, host, bound, entry)}{waits}"  # noqa: E731
    up.listening_banners = getattr(up, "listening_banners", []) + [(host, port_file, line)]
    procs: list[tuple[str, str, object]] = [(f"teacher.{prefix}", "services.console", console)]
    if up.webcam:
        from services.perception.config import PerceptionLiveConfig

        face = f"{prefix}-face"
        procs.append(
            (
                f"teacher.{face}",
                "services.perception",
                PerceptionLiveConfig(
                    **common,
                    stats_out=up.stats_path(f"teacher.{face}"),
                    source=f"zenoh:{WEBCAM}",
                    teacher_id=face,
                    camera=WEBCAM,
                    stop_with=("actor",),
                    screens=True,
                    screen_span=console.span,
                ),
            )
        )
    return procs
