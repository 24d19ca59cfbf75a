"""The launcher's configuration (`UpConfig`, also its command line) and the processes of a run."""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.agents import ALGOS, AgentConfig
from common.agents.config import agent_for
from common.config import nested, option
from common.core.credit import SCREEN_CREDIT
from common.core.delay import parse_probs
from common.core.delay_model import check_delay_estimate_spec
from common.core.observer import ObserverConfig
from common.core.task import Task
from common.protocol import teacher_id_of
from services.common.config import ActorConfig, FoxgloveConfig, LearnerConfig, RecorderConfig
from services.teacher.registry import TEACHERS, ProcessSpec, missing_extra


@dataclass(frozen=True)
class UpConfig:
    """Start a live run: an embedded Zenoh router and one process per service, with a progress bar and a
    summary at the end."""

    task: Task = option(Task(), "environment, layout, seed, teacher rule", flatten=True)
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    agent: AgentConfig | None = option(None, "the agent's hyper-parameters (default: the algo's preset; its "
                                             "assumed-delay-probs and update-interval are the flags below)",
                                       exclude=("algo", "assumed_delay_probs", "update_interval"))
    observer: ObserverConfig = option(ObserverConfig(), "the simulated observer")
    teacher: str = option("oracle", "teacher kind (services/teacher/registry.py)", choices=tuple(TEACHERS))
    teacher_id: str = option("oracle", "the teacher's name (its feedback key's last chunk)")
    episodes: int = option(50, "episodes the actor runs")
    max_steps: int | None = option(None, "the actor also stops after this many steps (none = no limit)")
    episode_steps: int | None = option(None, "the actor cuts an episode after this many steps (none = the env's own "
                                             "limit: 1000 for the maze and Taxi)")
    out: str = option("runs", "parent directory of the run's directory")
    run: str | None = option(None, "run name (default: live-<date>-<time>-<random>, unique)")
    rate: float = option(0.0, "actor steps per second; 0 = as fast as possible")
    start_paused: bool = option(False, "the actor waits, paused, for a resume before its first step (with --teacher "
                                       "web the console resumes it once the first page is open and has estimated "
                                       "its clock)")
    max_ahead: int | None = option(0, "steps the actor may run ahead of the weights it holds (0 = lockstep, as the "
                                      "in-process runner; more trades learning fidelity for throughput; none = never "
                                      "wait)")
    assumed_delay_probs: tuple[float, ...] = option((0.3333, 0.3333, 0.3334),
                                                    "lag distribution the learner assumes for credit (the agent's "
                                                    "assumed-delay-probs; face-video shifts it by its lag)")
    host: str = option("127.0.0.1", "address the router listens on (0.0.0.0 to let other machines join)")
    port: int = option(0, "router port; 0 = pick a free one")
    update_interval: int = option(1, "learner's b: Q and D_global minibatch updates every b steps (paper: 1; the "
                                     "agent's update-interval)")
    weights_every: int = option(16, "learner publishes weights whenever it has caught up, and at least every N "
                                    "learned steps while behind")
    end_grace: float = option(3.0, "learner's wait for teachers after the last step (s)")
    start_timeout: float = option(60.0, "seconds for all services to come up")
    stop_timeout: float = option(10.0, "seconds after the actor ends (or Ctrl-C) before stragglers are terminated")
    progress: bool = option(True, "show a progress bar")
    restart_limit: int = option(3, "restarts per service before the run is given up (0: a dead service stops the run)")
    restart_backoff: float = option(0.5, "seconds before the first restart of a service; doubles per restart, "
                                         "at most 8 s")
    checkpoint_period: float = option(2.0, "seconds between the learner's checkpoints")
    security: str | None = option(None, "security.json of the router machine (python -m common.security init): "
                                        "run the secured router (TLS on HOST:PORT) and connect every service to it")
    learner_inbox: int = option(1 << 16, "the learner's bounded input queue (steps + feedback)")
    max_lag: int = option(2048, "the actor never runs more than this many steps ahead of the learner's newest weights "
                                "(whatever max-ahead says): a bound on everything in flight")
    debug_update_sleep: float = option(0.0, "TEST ONLY: the learner sleeps this long after each step (slow learner)")
    debug_drop_steps: int = option(0, "TEST ONLY: the learner drops the first N steps as from an unannounced actor")
    screen_delay: str = option("learned", "--teacher web: delay in seconds between a step appearing on a person's "
                                          "screen and their feedback: learned per person online (from Deep TAMER's "
                                          "uniform 0.2-4 s), or fixed: uniform:LOW,HIGH or a scipy.stats NAME:ARGS "
                                          "(e.g. gamma:2,0.2,0.4)")
    screen_credit: str = option("onset", "--teacher web: credit at each step's appearance on screen (onset) or over "
                                         "its time on screen (interval, Deep TAMER's)", choices=SCREEN_CREDIT)
    oracle_delay: str = option("auto", "--teacher oracle/face-video: the learner's delay of that teacher: learned "
                                       "(in seconds, online), steps (assumed-delay-probs on the step clock, the "
                                       "paper's), a fixed NAME:ARGS in seconds, or auto: learned when the actor is "
                                       "paced (--rate > 0: a delay in seconds means something), else steps")
    profiles: str | None = option(None, "--teacher web: directory of returning people's delay estimates (a named "
                                        "person, ?name=alice, starts from DIR/web-alice.json; written as they teach)")
    idle_updates: int = option(0, "learner: extra minibatch steps between two steps while idle (--teacher web: 8)")
    console_port: int = option(0, "--teacher web: the console's web port (0 = pick a free one)")
    webcam: bool = option(False, "--teacher web: also start the perception service for the people's webcams")
    render_frames: bool = option(False, "the actor publishes the env's RGB render of each step (camera/env); "
                                        "--teacher web sets it for environments the console has no scene for")
    foxglove: int | None = option(None, "also serve the run's channels (as in the log) over Foxglove's WebSocket "
                                        "protocol on this port (services/foxglove; docs/logs.md)")
    foxglove_host: str = option("127.0.0.1", "address the Foxglove bridge serves on")
    hang_timeout: float = option(60.0, "a ready service that sends no status for this many seconds while its process "
                                       "runs is hung: killed and restarted like a dead one (a service whose Zenoh "
                                       "session lapses, e.g. stopped, is caught sooner by its liveliness token)")
    min_free_mb: float = option(16.0, "stop the run cleanly when the run directory's disk has less than this many "
                                      "MiB free (a full disk)")

    def __post_init__(self):
        object.__setattr__(self, "task", nested(self.task, Task))
        object.__setattr__(self, "observer", nested(self.observer, ObserverConfig, name="observer"))
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        if self.teacher not in TEACHERS:
            raise ValueError(f"unknown teacher {self.teacher!r}; choose one of {', '.join(TEACHERS)}")
        why = TEACHERS[self.teacher].available()
        if why:
            raise ValueError(f"teacher {self.teacher!r}: {why}")
        if self.foxglove is not None and (why := missing_extra("foxglove", "foxglove")):
            raise ValueError(f"foxglove: {why}")
        for name, value in TEACHERS[self.teacher].defaults(self).items():  # e.g. face-video's pace
            object.__setattr__(self, name, value)
        if self.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {self.episodes}")
        if not (math.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(f"rate must be >= 0, got {self.rate}")
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
        object.__setattr__(self, "assumed_delay_probs", parse_probs(self.assumed_delay_probs, "assumed-delay-probs"))
        check_delay_estimate_spec(self.screen_delay)
        if self.oracle_delay not in ("auto", "steps"):
            check_delay_estimate_spec(self.oracle_delay)
        if self.update_interval < 1:
            raise ValueError(f"update-interval must be >= 1, got {self.update_interval}")
        # One agent for learner and actor: the two launcher-level flags are its fields.
        object.__setattr__(self, "agent", dataclasses.replace(
            self.agent, assumed_delay_probs=self.assumed_delay_probs, update_interval=self.update_interval))

    # The task's fields, read by the teacher kinds and the report.
    env = property(lambda self: self.task.env)
    layout = property(lambda self: self.task.layout)
    seed = property(lambda self: self.task.seed)


class Launch:
    """What a teacher kind (and the launcher) builds service configs from: the UpConfig plus where things go."""

    def __init__(self, cfg: UpConfig, run: str, rundir: Path, endpoint: str):
        self.cfg, self.run, self.rundir, self.endpoint = cfg, run, rundir, endpoint
        self.connect_endpoints = (endpoint if cfg.host not in ("0.0.0.0", "::") else
                                  endpoint.replace(cfg.host, "127.0.0.1"),)
        self.parent_pid = os.getpid()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.cfg, name)

    def stats_path(self, service: str) -> str:
        return str(self.rundir / "stats" / f"{service}.json")

    def state_path(self, service: str, suffix: str = ".json") -> str:
        return str(self.rundir / "state" / f"{service}{suffix}")

    def credentials_path(self, identity: str) -> str:
        return str(self.rundir / "credentials" / f"{identity}.json")

    def common(self, service: str) -> dict:
        return dict(run=self.run, connect=self.connect_endpoints, parent_pid=self.parent_pid,
                    stats_out=self.stats_path(service), security=self.cfg.security,
                    credentials=self.credentials_path(service))


def oracle_delay(c: UpConfig) -> str:
    """The learner's delay of a teacher without a screen: `oracle_delay`, auto resolved by the actor's pace."""
    if c.oracle_delay == "auto":
        return "learned" if c.rate > 0 else "steps"
    return c.oracle_delay


def build_processes(launch: Launch) -> tuple[list[ProcessSpec], list[str]]:
    """The processes of a run, in start order, and the teacher service names."""
    c = launch.cfg
    teachers = TEACHERS[c.teacher].build(launch, c.teacher_id)
    if not teachers:
        raise ValueError(f"teacher kind {c.teacher!r} starts no process")
    teacher_names = [teachers[0].name]
    own_teachers = tuple(t for t in map(teacher_id_of, teacher_names) if t)  # (not a console's people)
    learner = LearnerConfig(**launch.common("learner"), task=c.task, algo=c.algo, agent=c.agent,
                            weights_every=c.weights_every,
                            end_grace=c.end_grace, wait_teachers=own_teachers, credits_in_ingest=own_teachers,
                            checkpoint=launch.state_path("learner", ".ckpt"), checkpoint_period=c.checkpoint_period,
                            catchup_log=str(launch.rundir / "session.mcap"), inbox_size=c.learner_inbox,
                            debug_update_sleep=c.debug_update_sleep, debug_drop_steps=c.debug_drop_steps,
                            screen_delay=c.screen_delay, oracle_delay=oracle_delay(c),
                            screen_credit=c.screen_credit, idle_updates=c.idle_updates, profiles=c.profiles)
    others = ["recorder", "learner"] + [t.name for t in teachers]
    actor = ActorConfig(**launch.common("actor"), task=c.task, algo=c.algo, agent=c.agent,
                        episodes=c.episodes, max_steps=c.max_steps, episode_steps=c.episode_steps, rate=c.rate,
                        max_ahead=c.max_ahead, wait_for=tuple(others),
                        start_paused=c.start_paused,
                        start_timeout=c.start_timeout, max_lag=c.max_lag, render_frames=c.render_frames,
                        # a restarted learner needs a few seconds (start, restore, catch up) before new weights
                        weights_timeout=120.0 if c.restart_limit else 30.0)
    recorder = RecorderConfig(**launch.common("recorder"), out=str(launch.rundir / "session.mcap"),
                              run_config=str(launch.rundir / "config" / "run.json"),
                              stop_when=tuple(["actor", "learner"] + teacher_names))
    procs = [ProcessSpec("recorder", "services.recorder", recorder),
             ProcessSpec("learner", "services.learner", learner), *teachers,
             ProcessSpec("actor", "services.actor", actor)]
    if c.foxglove:
        procs.insert(1, ProcessSpec("foxglove", "services.foxglove", FoxgloveConfig(
            **launch.common("foxglove"), port=c.foxglove, host=c.foxglove_host, run_config=recorder.run_config,
            stop_when=recorder.stop_when)))
        launch.banners = [*getattr(launch, "banners", []), f"foxglove: ws://{c.foxglove_host}:{c.foxglove} "
                                                           "(Foxglove: open connection, Foxglove WebSocket)"]
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
