"""Config dataclasses of the live services: each is documented, is the service's command line
(`common.config`), and is written to the run's log.

Every service shares `ServiceConfig` (run name, router endpoint, launcher link, stats file); the task
(`common.core.task.Task`: env, layout, seed, teacher rule), the agent (`AgentConfig`, `--agent.*`) and the
observer (`ObserverConfig`, `--observer.*`) are the same dataclasses as the in-process runner's, so a live
run and an in-process run with the same values are the same experiment.
"""

from __future__ import annotations

import math
from typing import Any
from dataclasses import dataclass, fields

from common.agents import ALGOS, AgentConfig
from common.agents.config import agent_for
from common.config import nested, option
from common.core.credit import SCREEN_CREDIT
from common.core.delay_model import check_delay_estimate_spec
from common.core.observer import ObserverConfig
from common.protocol import teacher_service_name
from common.core.task import Task
from services.common.service_config import CLOCKS, _check_name, ServiceConfig


@dataclass(frozen=True)
class TaskConfig(ServiceConfig):
    """The experiment: environment, layout, seed (same meaning as `python -m experiments run`)."""

    task: Task = option(Task(), "environment, layout, seed, teacher rule", flatten=True)
    max_future: float = option(10.0, "reject inputs stamped more than this many seconds after they arrive")
    max_past: float = option(600.0, "reject inputs stamped more than this many seconds before they arrive")
    resend_window: float = option(
        30.0,
        "re-send what was published in the last N s when a learner or recorder (re)starts (receivers drop duplicates)",
    )

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "task", nested(self.task, Task))
        for name in ("max_future", "max_past", "resend_window"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {v}")

    # The task's fields, read where the services used to have their own copies.
    env = property(lambda self: self.task.env)
    layout = property(lambda self: self.task.layout)
    seed = property(lambda self: self.task.seed)
    teacher_rule = property(lambda self: self.task.teacher_rule)


@dataclass(frozen=True)
class ActorSettings:
    """What a user sets of the actor: declared once, the actor's own (`ActorConfig` is these plus its wiring)
    and nested by the launcher (`UpConfig.actor`), the console and the scripted person."""

    episodes: int = option(50, "episodes to run, then stop")
    max_steps: int | None = option(None, "also stop after this many steps (none = no limit)")
    episode_steps: int | None = option(
        None,
        "cut an episode (truncated) after this many steps (none = the env's own limit: 1000 for the maze and Taxi)",
    )
    rate: float = option(0.0, "steps per second; 0 = as fast as possible")
    start_paused: bool = option(
        False,
        "wait paused, with no time limit, for a Control resume before the first step "
        "(a run taught in the console starts when its first page opens; a restarted "
        "actor does not wait)",
    )
    max_ahead: int | None = option(
        0,
        "act at step k only with weights that learned from step k-1-MAX_AHEAD or later "
        "(0 = lockstep with the learner, as the in-process runner, learns best; more "
        "trades fidelity for throughput; none = never wait)",
    )
    max_lag: int = option(
        2048,
        "whatever max-ahead says, never more than this many steps ahead of the learner's "
        "newest weights: bounds what is in flight and queued (back-pressure; docs/faults.md)",
    )
    render_frames: bool = option(
        False,
        "publish the env's RGB render after each step as JPEG on hitl/<run>/camera/env "
        "(the console shows environments it has no scene for)",
    )

    def __post_init__(self):
        if self.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {self.episodes}")
        if self.max_steps is not None and self.max_steps < 0:
            raise ValueError(f"max-steps must be >= 0 or none, got {self.max_steps}")
        if self.episode_steps is not None and self.episode_steps < 1:
            raise ValueError(f"episode-steps must be >= 1 or none, got {self.episode_steps}")
        if not (math.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(f"rate must be >= 0, got {self.rate}")
        if self.max_ahead is not None and self.max_ahead < 0:
            raise ValueError(f"max-ahead must be >= 0 or none, got {self.max_ahead}")
        if self.max_lag < 0:
            raise ValueError(f"max-lag must be >= 0, got {self.max_lag}")


@dataclass(frozen=True)
class ActorConfig(TaskConfig, ActorSettings):
    """The actor: steps the environment, acts with the newest weights it has, publishes every Step."""

    algo: str = option("dqn-tamer", "agent (sets the exploration and mixing schedules)", choices=ALGOS)
    agent: AgentConfig | None = option(
        None,
        "the agent's hyper-parameters (default: the algo's preset); the actor uses its network and schedules",
        exclude=("algo",),
    )
    wait_for: tuple[str, ...] = option(("learner",), "services that must be alive before the first step")
    start_timeout: float = option(60.0, "seconds to wait for those services")
    weights_timeout: float = option(30.0, "seconds to wait for fresh enough weights before giving up")
    stall_resend: float = option(
        2.0,
        "waiting this many seconds for fresh enough weights, re-send the steps the "
        "learner has not learned (one dropped before the learner knew this actor "
        "would otherwise stall the lockstep for good)",
    )
    state_file: str | None = option(
        None,
        "progress file (episodes done), rewritten in place "
        "(services/common/progress.py) at each episode end; "
        "an actor started on an existing one is a restart: it continues with the "
        "next episode and waits for the learner's current weights first",
    )

    def __post_init__(self):
        super().__post_init__()
        ActorSettings.__post_init__(self)
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(ALGOS)}")
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        if not self.stall_resend > 0:
            raise ValueError(f"stall-resend must be > 0 seconds, got {self.stall_resend}")
        for name in self.wait_for:
            _check_name(name, "wait-for")


@dataclass(frozen=True)
class TeacherConfig(TaskConfig):
    """The simulated teacher: the core's SimulatedObserver reacting on its own clock to the steps it sees."""

    teacher_id: str = option("oracle", "teacher name (last chunk of its feedback key)")
    observer: ObserverConfig = option(ObserverConfig(), "the simulated observer")
    clock: str = option(
        "steps",
        "steps: a reaction to step k with lag d is sent once step k+d+1 is seen, stamped "
        "half-way between steps k+d and k+d+1; wall: sent at t_action(k) + (d + 0.5) * "
        "step-unit seconds (for a fixed actor rate)",
        choices=CLOCKS,
    )
    step_unit: float = option(0.1, "seconds per step for --clock wall (1 / the actor's rate)")
    state_file: str | None = option(
        None,
        "the next feedback seq, rewritten in place (services/common/progress.py) "
        "before each feedback is sent: a restarted teacher continues its seq "
        "(never reuses one)",
    )

    def __post_init__(self):
        super().__post_init__()
        _check_name(self.teacher_id, "teacher-id")
        object.__setattr__(self, "observer", nested(self.observer, ObserverConfig, name="observer"))
        if self.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, got {self.clock!r}")
        if not (math.isfinite(self.step_unit) and self.step_unit > 0):
            raise ValueError(f"step-unit must be positive, got {self.step_unit}")

    @property
    def service_name(self) -> str:
        return teacher_service_name(self.teacher_id)


@dataclass(frozen=True)
class LearnerSettings:
    """What a user sets of the learner: declared once, the learner's own (`LearnerConfig` is these plus its
    wiring) and nested by the launcher (`UpConfig.learner`), the console and the scripted person."""

    idle_updates: int = option(
        0,
        "extra Q and D_global minibatch steps between two steps when no input came for "
        "50 ms (a paced run's idle time; recorded in the Ingest order, so retrain repeats "
        "them; 0 = the paper's schedule only)",
    )
    screen_delay: str = option(
        "learned",
        "delay in seconds from a step on a person's screen (the console) to their "
        "feedback: learned (per person, online, from Deep TAMER's uniform 0.2-4 s; "
        "learned:PRIOR for another prior), or fixed: uniform:LOW,HIGH or any "
        "scipy.stats distribution NAME:ARGS, e.g. gamma:2,0.2,0.4 (shape, loc, "
        "scale); common.core.delay_model",
    )
    oracle_delay: str = option(
        "auto",
        "delay of a teacher without a screen (the oracle: stamps on the wall clock): "
        "steps (the agent's assumed-delay-probs on the step clock, the paper's), "
        "learned (in seconds, per teacher, as screen-delay), a fixed NAME:ARGS in "
        "seconds, or auto: learned when the actor is paced (a delay in seconds means "
        "something), else steps (a learner started by hand: steps)",
    )
    screen_credit: str = option(
        "onset",
        "how a step's time on a person's screen enters credit: interval (Deep "
        "TAMER: the delay's probability over the time it was shown) or onset "
        "(the person reacts to its appearance: the delay's density at the time "
        "since it appeared, normalised over the steps shown)",
        choices=SCREEN_CREDIT,
    )
    profiles: str | None = option(
        None,
        "directory of returning people's delay estimates: a named person "
        "(web-alice) starts from DIR/web-alice.json and it is rewritten as they "
        "teach (services/learner/teacher_delays.py)",
    )
    history_s: float = option(
        60.0,
        "seconds of recent steps a feedback may still be credited to (a press that "
        "comes later is counted as feedback_too_old): the credit rule's longest delay "
        "(6 s) plus a console restart or a lagging learner; 0: the agent's "
        "history-steps instead, a count (the in-process runner's)",
    )
    history_max_steps: int = option(4096, "but at most this many steps (memory: each holds its observation)")
    weights_every: int = option(
        16, "publish weights whenever the learner has caught up, and at least every N learned steps while it is behind"
    )
    end_grace: float = option(3.0, "after the actor's last step, seconds to wait for teachers still sending")
    reorder_wait: float = option(
        2.0, "seconds a live step ahead of the next expected one waits for those before it (re-sent after a restart)"
    )
    checkpoint_period: float = option(2.0, "seconds between checkpoints at most (when something was learned)")
    checkpoint_steps: int = option(100, "new steps learned before the next checkpoint (a paced run's rarer ones)")
    inbox_size: int = option(
        1 << 16,
        "the learner's bounded input queue (steps + feedback); when full, Zenoh's BLOCK "
        "congestion control slows the publishers down",
        was=("--learner-inbox",),
    )
    debug_update_sleep: float = option(
        0.0, "TEST ONLY: sleep this many seconds after each learned step (a deliberately slow learner)"
    )
    debug_drop_steps: int = option(
        0,
        "TEST ONLY: drop the first N steps as if their actor were not announced yet "
        "(what a late announcement does on a loaded machine)",
    )

    def __post_init__(self):
        check_delay_estimate_spec(self.screen_delay)  # a one-line ValueError if malformed
        if self.oracle_delay not in ("auto", "steps"):
            check_delay_estimate_spec(self.oracle_delay)
        if self.screen_credit not in SCREEN_CREDIT:
            raise ValueError(f"screen-credit must be one of {', '.join(SCREEN_CREDIT)}, got {self.screen_credit!r}")
        if self.screen_credit == "onset" and self.screen_delay.strip().startswith("steps"):
            raise ValueError("screen-credit onset needs a delay in seconds with a density, not steps:...")
        for name in ("weights_every", "checkpoint_steps", "inbox_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        for name in ("end_grace", "reorder_wait", "debug_update_sleep"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")
        if not (math.isfinite(self.checkpoint_period) and self.checkpoint_period > 0):
            raise ValueError(f"checkpoint-period must be positive, got {self.checkpoint_period}")
        if not (math.isfinite(self.history_s) and self.history_s >= 0) or self.history_max_steps < 1:
            raise ValueError(
                f"history-s must be >= 0 and history-max-steps >= 1, got {self.history_s}, {self.history_max_steps}"
            )
        for name in ("idle_updates", "debug_drop_steps"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")

    def resolved_oracle_delay(self, rate: float) -> str:
        """`oracle_delay` with auto resolved by the actor's pace (`rate` steps/s; 0 = as fast as possible)."""
        if self.oracle_delay == "auto":
            return "learned" if rate > 0 else "steps"
        return self.oracle_delay


@dataclass(frozen=True)
class LearnerConfig(TaskConfig, LearnerSettings):
    """The learner: aligns feedback to steps by timestamp, trains Q and H, publishes weights and episodes."""

    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    agent: AgentConfig | None = option(
        None,
        "the agent's hyper-parameters (default: the algo's preset; "
        "update-interval b > 1 trades learning per step for throughput)",
        exclude=("algo",),
    )
    snapshot_every: int = option(
        500,
        "log the weights (a WeightsSnapshot) every N learned steps, besides the first, "
        "each episode end (numbers only), on request and the final ones",
    )
    ingest_batch: int = option(64, "at most this many entries per Ingest message")
    ingest_period: float = option(
        0.5,
        "seconds an entry may wait for its Ingest message (one message per period or ingest-batch entries, "
        "not one per step: each message costs every process on its way)",
    )
    wait_teachers: tuple[str, ...] = option((), "teacher ids to wait for at the end (besides those seen)")
    credits_in_ingest: tuple[str, ...] = option(
        (),
        "teacher ids whose Credits ride in the next Ingest message "
        "instead of one message each (the launcher: its own teachers; a "
        "person's console wants each at once, on its own key)",
    )
    checkpoint: str | None = option(
        None,
        "checkpoint file: restored at start if it exists, rewritten atomically "
        "every checkpoint-period s while learning",
    )
    catchup_log: str | None = option(
        None,
        "the run's MCAP log (first segment): at start, consume the steps and "
        "feedback it holds beyond the checkpoint (none: only what arrives live)",
    )

    def __post_init__(self):
        super().__post_init__()
        LearnerSettings.__post_init__(self)
        # auto needs the actor's pace, which a learner does not know: the launcher resolves it; by hand, steps
        object.__setattr__(self, "oracle_delay", self.resolved_oracle_delay(0.0))
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(ALGOS)}")
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        if self.snapshot_every < 1:
            raise ValueError(f"snapshot-every must be >= 1, got {self.snapshot_every}")
        if not (math.isfinite(self.ingest_period) and 0 <= self.ingest_period <= 10):
            raise ValueError(f"ingest-period must be in 0..10 s, got {self.ingest_period}")
        if not 1 <= self.ingest_batch <= 2048:
            raise ValueError(f"ingest-batch must be in 1..2048, got {self.ingest_batch}")


@dataclass(frozen=True)
class RecorderConfig(ServiceConfig):
    """The recorder: everything under hitl/<run>/** into one MCAP file."""

    out: str = option("runs/live/session.mcap", "MCAP file to write (later segments beside it)")
    run_config: str | None = option(
        None, "JSON file whose object becomes the log's run config (default: this recorder's own config)"
    )
    stop_when: tuple[str, ...] = option(
        (), "finish once all these services have reported state 'stopped' (empty: only on SIGTERM / Ctrl-C)"
    )
    flush_interval: float = option(0.5, "seconds between MCAP chunk flushes while data is pending")
    linger: float = option(0.3, "seconds to keep recording after the last awaited service stopped")
    max_sender_mb_s: float = option(
        32.0,
        "write at most this many MiB per second from any one sender (the rest is "
        "counted as capped_<kind>): a flood cannot fill the disk",
    )
    max_camera_mb_s: float = option(4.0, "and at most this many MiB per second of frames per camera")
    max_camera_fps: float = option(60.0, "and at most this many frames per second per camera")

    def __post_init__(self):
        super().__post_init__()
        for name in self.stop_when:
            _check_name(name, "stop-when")
        if not (math.isfinite(self.flush_interval) and self.flush_interval > 0):
            raise ValueError(f"flush-interval must be positive, got {self.flush_interval}")
        for name in ("max_sender_mb_s", "max_camera_mb_s", "max_camera_fps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name.replace('_', '-')} must be positive, got {v}")


@dataclass(frozen=True)
class FoxgloveConfig(ServiceConfig):
    """The Foxglove bridge: the run's channels, as the log has them, over Foxglove's WebSocket protocol."""

    port: int = option(8765, "WebSocket port Foxglove connects to (ws://HOST:PORT; 0: a free one, chosen at the bind)")
    port_file: str | None = option(None, "where to write the port it serves on (the launcher prints it from there)")
    host: str = option("127.0.0.1", "address to serve on (127.0.0.1: this machine only)")
    run_config: str | None = option(None, "the run's run.json (the environment to draw); none: no scene")
    stop_when: tuple[str, ...] = option(
        (), "stop once all these services have reported 'stopped' (empty: on SIGTERM / Ctrl-C only)"
    )
    linger: float = option(1.0, "seconds to keep serving after the last awaited service stopped")

    def __post_init__(self):
        super().__post_init__()
        if not 0 <= self.port < 65536:
            raise ValueError(f"port must be in 0..65535, got {self.port}")
        for name in self.stop_when:
            _check_name(name, "stop-when")
        if not (math.isfinite(self.linger) and self.linger >= 0):
            raise ValueError(f"linger must be >= 0, got {self.linger}")


def learner_config_from_record(record: dict) -> LearnerConfig:
    """Inverse of `LearnerCore.config_record()['learner']`."""
    known = {f.name for f in fields(LearnerConfig)}
    data: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in record.items() if k in known}
    data.setdefault("history_s", 0.0)  # a log recorded before history_s held the agent's step count: retrain as it ran
    return LearnerConfig(**data)
