"""The console's config: where it listens, who may teach through it, and what it accepts from a page."""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.agents import ALGOS, AgentConfig
from common.agents.config import agent_for
from common.config import Groups, all_but, nested, option
from common.core.delay import delay_from_spec
from common.core.delay_model import LearnedDelayConfig, is_learned
from common.protocol import MAX_RATE
from services.common.config import ActorSettings, LearnerSettings, TaskConfig, _check_name


@dataclass(frozen=True)
class ConsoleSettings:
    """What a user sets of the console: declared once, the console's own (`ConsoleConfig` is these plus its
    wiring) and nested by the launcher (`UpConfig.console`: `--console.port`, `--console.max-people`, ...)."""

    port: int = option(8765, "web server port (0: a free one, chosen when the console binds; services up: 0)")
    server_names: tuple[str, ...] = option(
        (),
        "more names the page may reach the console by (its Host header), "
        "comma-separated: e.g. the machine's DNS name with --host 0.0.0.0 "
        "and --security; loopback names and --host always pass",
    )
    max_people: int = option(8, "pages that may be open at once (a page idle for idle-timeout s is closed)")
    idle_timeout: float = option(30.0, "close a page that sent nothing for this many seconds (a page pings every 2 s)")
    max_control_rate: float = option(
        2.0,
        "pace / pause / resume / end controls per second accepted per person "
        "(bursts of 5; more are dropped and counted)",
    )
    max_frame_bytes: int = option(400_000, "largest webcam frame accepted (JPEG bytes)")
    max_frame_rate: float = option(15.0, "webcam frames per second accepted per person (more are dropped)")
    max_press_rate: float = option(8.0, "feedback presses per second accepted per person (a flood is dropped)")
    max_clock_skew: float = option(
        5.0, "reject a page time that maps more than this many seconds from the server's clock (absurd timestamps)"
    )
    header_timeout: float = option(
        10.0,
        "close a connection that has not sent a whole request header this many "
        "seconds after opening (a slow-header attack), before it presented a key",
    )
    unauthenticated_idle: float = option(
        10.0,
        "close a connection idle this many seconds between requests that never "
        "presented a key (a person's page presents one at once)",
    )
    max_connections_per_address: int = option(
        64, "connections one client address may hold before the oldest without a key is closed to make room"
    )
    max_connections: int = option(256, "connections held in all before the oldest without a key is closed")
    stop_after: float = option(3.0, "seconds to keep serving after the learner stopped (the page shows the end)")

    def __post_init__(self):
        if not 0 <= self.port < 65536:
            raise ValueError(f"port must be in 0..65535, got {self.port}")
        for name in (
            "max_frame_rate",
            "max_press_rate",
            "max_clock_skew",
            "stop_after",
            "idle_timeout",
            "max_control_rate",
            "header_timeout",
            "unauthenticated_idle",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name.replace('_', '-')} must be positive, got {v}")
        if min(self.max_people, self.max_frame_bytes, self.max_connections, self.max_connections_per_address) < 1:
            raise ValueError(
                "max-people, max-frame-bytes, max-connections and max-connections-per-address must be >= 1"
            )


@dataclass(frozen=True)
class ConsoleConfig(TaskConfig, ConsoleSettings, Groups):
    """The console: one web page per person, bridged to the run over a WebSocket. A person watches the agent
    (environment picture, learning curve, Q and H per action), teaches it with keys, buttons or their webcam,
    and paces, pauses or ends the run. Each open page is its own teacher (`<teacher-prefix>-<n>`); its feedback
    is stamped with the person's action time on the system clock and lists the steps their screen showed."""

    algo: str = option("dqn-tamer", "agent (for Q, H and alpha_h shown on the page)", choices=ALGOS)
    agent: AgentConfig | None = option(None, "the run's agent (its network holds the weights shown)", exclude=("algo",))
    host: str = option("127.0.0.1", "address the web server listens on (anything but loopback needs --security)")
    teacher_prefix: str = option(
        "web",
        "people are teachers <prefix>-1, <prefix>-2, ... in the order they open "
        "the page (or <prefix>-<name> with ?name=NAME)",
    )
    actor: ActorSettings = option(
        ActorSettings(),
        "the run's actor: its pace at start (shown on the page), its "
        "episodes (the learning curve's width), and start-paused: it "
        "waits until the first page opens, then this console resumes it",
        flatten=True,
        exclude=all_but(ActorSettings, "rate", "episodes", "start_paused"),
        was={"start_paused": "--start-on-first-page"},
    )
    learner: LearnerSettings = option(
        LearnerSettings(),
        "the run's learner: its screen delay's longest value sets "
        "how far back a feedback lists the steps shown (6 s for a "
        "learned one)",
        flatten=True,
        exclude=all_but(LearnerSettings, "screen_delay"),
    )
    camera: str | None = option(
        None,
        "camera id to publish webcam frames on (hitl/<run>/camera/<camera>) for the "
        "perception service; none = no webcam panel",
    )
    state_file: str | None = option(
        None,
        "the press ledger (services/console/people.py), rewritten before each "
        "feedback: a restarted console continues every person's seq and "
        "recognises presses their pages re-send",
    )
    token_file: str | None = option(
        None,
        "file holding the console's secret (made, mode 0600, if missing; the "
        "launcher puts it in the run directory): every key of the printed "
        "addresses and pages derives from it. None: a new secret per start",
    )
    port_file: str | None = option(
        None,
        "file the console writes the port it listens on to (the launcher reads "
        "it for the address it prints); with port 0 a restarted console listens "
        "on the port written there, so that open pages reconnect",
    )
    replay: str | None = option(
        None,
        "instead of joining a run: serve this session.mcap (or run directory) as a "
        "replay with a timeline to scrub (services/console/replay.py)",
    )

    def __post_init__(self):
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        object.__setattr__(self, "actor", nested(self.actor, ActorSettings, name="actor"))
        object.__setattr__(self, "learner", nested(self.learner, LearnerSettings, name="learner"))
        super().__post_init__()
        ConsoleSettings.__post_init__(self)
        _check_name(self.teacher_prefix, "teacher-prefix")
        if self.camera is not None:
            _check_name(self.camera, "camera")
        if not self.rate <= MAX_RATE:  # (the actor's own check: >= 0, 0 = as fast as possible)
            raise ValueError(f"rate must be at most {MAX_RATE}, got {self.rate}")

    @property
    def start_on_first_page(self) -> bool:
        """The actor starts paused: this console resumes it when the first page opens."""
        return self.actor.start_paused

    @property
    def span(self) -> float:
        """How far back (s) a feedback may reach: the assumed delay's largest value (its 99.9th percentile if
        unbounded; a learned delay's range)."""
        if is_learned(self.screen_delay):
            return LearnedDelayConfig().max_s
        d = delay_from_spec(self.screen_delay)
        top = float(d.ppf(1.0)) if hasattr(d, "ppf") else float(getattr(d, "max_lag", 4.0))
        return top if math.isfinite(top) else float(d.ppf(0.999))
