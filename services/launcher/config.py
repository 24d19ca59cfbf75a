"""The launcher's configuration (`UpConfig`, also its command line) and the processes of a run."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.agents import ALGOS, AgentConfig
from common.agents.config import agent_for
from common.config import Groups, nested, option
from common.core.observer import ObserverConfig
from common.core.task import Task
from common.protocol import teacher_id_of
from services.common.config import (
    ActorConfig,
    ActorSettings,
    FoxgloveConfig,
    LearnerConfig,
    LearnerSettings,
    RecorderConfig,
)
from services.console.config import ConsoleSettings
from services.teacher.registry import TEACHERS, ProcessSpec, missing_extra


@dataclass(frozen=True)
class UpConfig(Groups):
    """Start a live run: an embedded Zenoh router and one process per service, with a progress bar and a
    summary at the end."""

    task: Task = option(Task(), "environment, layout, seed, teacher rule", flatten=True)
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    agent: AgentConfig | None = option(
        None,
        "the agent's hyper-parameters (default: the algo's preset), the actor's and the learner's",
        exclude=("algo",),
        was={"assumed_delay_probs": "--assumed-delay-probs", "update_interval": "--update-interval"},
    )
    actor: ActorSettings = option(
        ActorSettings(), "the actor's settings (services.actor: the same flags)", flatten=True
    )
    learner: LearnerSettings = option(
        LearnerSettings(),
        "the learner's settings (services.learner: the same flags; "
        "screen-delay and screen-credit are for --teacher web, "
        "oracle-delay for --teacher oracle/face-video)",
        flatten=True,
    )
    observer: ObserverConfig = option(ObserverConfig(), "the simulated observer")
    teacher: str = option("oracle", "teacher kind (services/teacher/registry.py)", choices=tuple(TEACHERS))
    teacher_id: str = option("oracle", "the teacher's name (its feedback key's last chunk)")
    out: str = option("runs", "parent directory of the run's directory")
    run: str | None = option(None, "run name (default: live-<date>-<time>-<random>, unique)")
    host: str = option("127.0.0.1", "address the router listens on (0.0.0.0 to let other machines join)")
    port: int = option(0, "router port; 0 = pick a free one")
    start_timeout: float = option(60.0, "seconds for all services to come up")
    stop_timeout: float = option(10.0, "seconds after the actor ends (or Ctrl-C) before stragglers are terminated")
    progress: bool = option(True, "show a progress bar")
    curve: bool = option(True, "draw learning_curve.png at the end (matplotlib: about 1 s of CPU)")
    restart_limit: int = option(3, "restarts per service before the run is given up (0: a dead service stops the run)")
    restart_backoff: float = option(
        0.5, "seconds before the first restart of a service; doubles per restart, at most 8 s"
    )
    security: str | None = option(
        None,
        "security.json of the router machine (python -m services security init): "
        "run the secured router (TLS on HOST:PORT) and connect every service to it",
    )
    console: ConsoleSettings = option(
        ConsoleSettings(port=0),
        "--teacher web: the console's settings (services.console: the same flags, here --console.*)",
        was={"port": "--console-port"},
    )
    webcam: bool = option(False, "--teacher web: also start the perception service for the people's webcams")
    foxglove: int | None = option(
        None,
        "also serve the run's channels (as in the log) over Foxglove's WebSocket "
        "protocol on this port (0: a free one, printed once it listens; services/foxglove; docs/logs.md)",
    )
    foxglove_host: str = option("127.0.0.1", "address the Foxglove bridge serves on")
    hang_timeout: float = option(
        60.0,
        "a ready service that sends no status for this many seconds while its process "
        "runs is hung: killed and restarted like a dead one (a service whose Zenoh "
        "session lapses, e.g. stopped, is caught sooner by its liveliness token)",
    )
    min_free_mb: float = option(
        16.0, "stop the run cleanly when the run directory's disk has less than this many MiB free (a full disk)"
    )

    def __post_init__(self):
        object.__setattr__(self, "task", nested(self.task, Task))
        object.__setattr__(self, "observer", nested(self.observer, ObserverConfig, name="observer"))
        object.__setattr__(self, "actor", nested(self.actor, ActorSettings))
        object.__setattr__(self, "learner", nested(self.learner, LearnerSettings))
        from_preset = lambda **given: dataclasses.replace(ConsoleSettings(port=0), **given)  # noqa: E731
        object.__setattr__(self, "console", nested(self.console, ConsoleSettings, build=from_preset, name="console"))
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        if self.teacher not in TEACHERS:
            raise ValueError(f"unknown teacher {self.teacher!r}; choose one of {', '.join(TEACHERS)}")
        why = TEACHERS[self.teacher].available()
        if why:
            raise ValueError(f"teacher {self.teacher!r}: {why}")
        if self.foxglove is not None and not 0 <= self.foxglove < 65536:
            raise ValueError(f"foxglove: port must be in 0..65535 (0: a free one), got {self.foxglove}")
        if self.foxglove is not None and (why := missing_extra("foxglove", "foxglove")):
            raise ValueError(f"foxglove: {why}")
        self._apply(TEACHERS[self.teacher].defaults(self))  # e.g. face-video's pace
        if not 0 <= self.port < 65536:
            raise ValueError(f"port must be in 0..65535, got {self.port}")
        if self.restart_limit < 0:
            raise ValueError(f"restart-limit must be >= 0, got {self.restart_limit}")
        for name in ("hang_timeout", "min_free_mb"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name.replace('_', '-')} must be positive, got {v}")
        if not (math.isfinite(self.restart_backoff) and self.restart_backoff >= 0):
            raise ValueError(f"restart-backoff must be >= 0, got {self.restart_backoff}")

    @classmethod
    def flat(cls, **settings: Any) -> UpConfig:
        """An UpConfig from settings named as their flags are (`rate=`, `end_grace=`, `update_interval=`), each
        put in the group that declares it: for Python callers, as the command line has them."""
        own = {f.name for f in dataclasses.fields(cls)}
        given: dict[str, Any] = {k: v for k, v in settings.items() if k in own}
        groups: tuple[tuple[str, type], ...] = (
            ("task", Task),
            ("actor", ActorSettings),
            ("learner", LearnerSettings),
            ("agent", AgentConfig),
        )
        placed = set(given)
        for group, of in groups:
            names = {f.name for f in dataclasses.fields(of)} - own
            part = {k: v for k, v in settings.items() if k in names}
            if part:
                whole: Any = given.get(group)  # a dict, None or already a `of`
                if isinstance(whole, of):
                    whole = {f.name: getattr(whole, f.name) for f in dataclasses.fields(of) if f.init}
                given[group] = {**(whole or {}), **part}
                placed |= set(part)
        unknown = sorted(set(settings) - placed)
        if unknown:
            raise ValueError(f"unknown setting {unknown[0]!r}")
        return cls(**given)

    def _apply(self, changes: dict[str, Any]) -> None:
        """A teacher kind's changes to the defaults, each to the group that declares it (rate: the actor's)."""
        for name, value in changes.items():
            group = next((g for g in ("actor", "learner", "agent") if hasattr(getattr(self, g), name)), None)
            if group is None:
                object.__setattr__(self, name, value)
            else:
                object.__setattr__(self, group, dataclasses.replace(getattr(self, group), **{name: value}))

    # The task's fields, read by the teacher kinds and the report.
    env = property(lambda self: self.task.env)
    layout = property(lambda self: self.task.layout)
    seed = property(lambda self: self.task.seed)


class Launch:
    """What a teacher kind (and the launcher) builds service configs from: the UpConfig plus where things go."""

    def __init__(self, cfg: UpConfig, run: str, rundir: Path, endpoint: str):
        self.cfg, self.run, self.rundir, self.endpoint = cfg, run, rundir, endpoint
        self.connect_endpoints = (
            endpoint if cfg.host not in ("0.0.0.0", "::") else endpoint.replace(cfg.host, "127.0.0.1"),
        )
        self.parent_pid: int | None = os.getpid()
        # (host, port file, line of the port): printed once the port written to that file listens
        self.listening_banners: list[tuple[str, str, Callable[[int], str]]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.cfg, name)

    def stats_path(self, service: str) -> str:
        return str(self.rundir / "stats" / f"{service}.json")

    def state_path(self, service: str, suffix: str = ".json") -> str:
        return str(self.rundir / "state" / f"{service}{suffix}")

    def credentials_path(self, identity: str) -> str:
        return str(self.rundir / "credentials" / f"{identity}.json")

    def common(self, service: str) -> dict:
        return dict(
            run=self.run,
            connect=self.connect_endpoints,
            parent_pid=self.parent_pid,
            stats_out=self.stats_path(service),
            security=self.cfg.security,
            credentials=self.credentials_path(service),
        )


def settings(group: Any) -> dict[str, Any]:
    """A settings group's values, to build the service config that declares them."""
    return {f.name: getattr(group, f.name) for f in dataclasses.fields(group)}


def build_processes(launch: Launch) -> tuple[list[ProcessSpec], list[str]]:
    """The processes of a run, in start order, and the teacher service names."""
    c = launch.cfg
    teachers = TEACHERS[c.teacher].build(launch, c.teacher_id)
    if not teachers:
        raise ValueError(f"teacher kind {c.teacher!r} starts no process")
    teacher_names = [teachers[0].name]
    own_teachers = tuple(t for t in map(teacher_id_of, teacher_names) if t)  # (not a console's people)
    learner = LearnerConfig(
        **launch.common("learner"),
        task=c.task,
        algo=c.algo,
        agent=c.agent,
        **{**settings(c.learner), "oracle_delay": c.learner.resolved_oracle_delay(c.rate)},
        wait_teachers=own_teachers,
        credits_in_ingest=own_teachers,
        checkpoint=launch.state_path("learner", ".ckpt"),
        catchup_log=str(launch.rundir / "session.mcap"),
    )
    others = ["recorder", "learner"] + [t.name for t in teachers]
    actor = ActorConfig(
        **launch.common("actor"),
        task=c.task,
        algo=c.algo,
        agent=c.agent,
        **settings(c.actor),
        wait_for=tuple(others),
        start_timeout=c.start_timeout,
        # a restarted learner needs a few seconds (start, restore, catch up) before new weights
        weights_timeout=120.0 if c.restart_limit else 30.0,
    )
    recorder = RecorderConfig(
        **launch.common("recorder"),
        out=str(launch.rundir / "session.mcap"),
        run_config=str(launch.rundir / "config" / "run.json"),
        stop_when=tuple(["actor", "learner"] + teacher_names),
    )
    procs = [
        ProcessSpec("recorder", "services.recorder", recorder),
        ProcessSpec("learner", "services.learner", learner),
        *teachers,
        ProcessSpec("actor", "services.actor", actor),
    ]
    if c.foxglove is not None:
        port_file = launch.state_path("foxglove", ".port")  # (port 0: the bridge's bind chooses it)
        Path(port_file).unlink(missing_ok=True)
        procs.insert(
            1,
            ProcessSpec(
                "foxglove",
                "services.foxglove",
                FoxgloveConfig(
                    **launch.common("foxglove"),
                    port=c.foxglove,
                    port_file=port_file,
                    host=c.foxglove_host,
                    run_config=recorder.run_config,
                    stop_when=recorder.stop_when,
                ),
            ),
        )
        line = lambda port: f"foxglove: ws://{c.foxglove_host}:{port} (Foxglove: open connection, Foxglove WebSocket)"  # noqa: E731
        launch.listening_banners.append((c.foxglove_host, port_file, line))  # (printed once it listens)
    # Whatever a teacher kind built: the run's security file, each service's credential file, and a progress
    # file where the service keeps one.
    fields = lambda cfg: {f.name for f in dataclasses.fields(cfg)}  # noqa: E731
    for i, p in enumerate(procs):
        extra = {}
        if "security" in fields(p.config) and p.config.security is None and c.security:
            extra["security"] = c.security
        if "credentials" in fields(p.config) and p.config.credentials is None:
            extra["credentials"] = launch.credentials_path(p.name)
        if "state_file" in fields(p.config) and p.config.state_file is None:
            extra["state_file"] = launch.state_path(p.name)
        if extra:
            procs[i] = dataclasses.replace(p, config=dataclasses.replace(p.config, **extra))
    return procs, teacher_names
