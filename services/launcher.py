"""`python -m services up`: a whole live run on this machine.

Starts an embedded Zenoh router (this process's own session in router mode, listening on HOST:PORT, no
multicast scouting), spawns one process per service (recorder, learner, the teacher's processes, actor; each
in its own process group, each told to exit if this process disappears), shows a progress bar fed by the
learner's EpisodeSummary messages, and stops everything at the end or on Ctrl-C: the actor is asked to stop
(SIGTERM), the others then finish on their own (teacher -> learner -> recorder); whatever is still running
after `stop_timeout` s gets SIGTERM, then SIGKILL 3 s later. Leaves in OUT/RUN/: session.mcap (and later
segments), summary.json, learning_curve.png, config/<service>.json, logs/<service>.log, stats/<service>.json,
state/ (the learner's checkpoint, the actor's and teachers' progress files).

Supervision (docs/faults.md): a service that dies (non-zero exit or a signal) before the run is over is
started again with the same config after a back-off (`restart_backoff` s, doubling, at most 8 s), at most
`restart_limit` times per service; the launcher says so on screen and as foxglove.Log records on
`hitl/<run>/log/launcher` (re-sent when the recorder itself comes back), and lists every restart in
summary.json. Past the limit it stops the run as before (exit code 1). With `security` the embedded router is
the secured one (TLS, user/password, access control: common/security.py) and every service connects with it.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.agents import ALGOS
from common.config import config_record, option
from common.delay import parse_probs
from common.envs import ENV_NAMES
from services.common.config import (ActorConfig, FoxgloveConfig, LearnerConfig, RecorderConfig, ServiceConfig,
                                    teacher_service_name)
from services.teacher.registry import TEACHERS, ProcessSpec

ROOT = Path(__file__).resolve().parents[1]
KILL_AFTER = 3.0  # s between SIGTERM and SIGKILL


@dataclass(frozen=True)
class UpConfig:
    """Start a live run: an embedded Zenoh router and one process per service, with a progress bar and a
    summary at the end."""

    env: str = option("maze", "environment", choices=ENV_NAMES)
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    teacher: str = option("oracle", "teacher kind (services/teacher/registry.py)", choices=tuple(TEACHERS))
    teacher_id: str = option("oracle", "the teacher's name (its feedback key's last chunk)")
    episodes: int = option(50, "episodes the actor runs")
    max_steps: int | None = option(None, "the actor also stops after this many steps (none = no limit)")
    out: str = option("runs", "parent directory of the run's directory")
    run: str | None = option(None, "run name (default: live-<date>-<time>)")
    seed: int = option(0, "trial seed (network init, exploration, observer, replay sampling, env)")
    layout: int = option(0, "maze layout 0..9")
    rate: float = option(0.0, "actor steps per second; 0 = as fast as possible")
    max_ahead: int | None = option(0, "steps the actor may run ahead of the weights it holds (0 = lockstep, as the "
                                      "in-process runner; more trades learning fidelity for throughput; none = never "
                                      "wait)")
    p_feedback: float = option(0.5, "probability that the simulated observer gives feedback on a step")
    delay_probs: tuple[float, ...] = option((0.3, 0.6, 0.1), "observer's true lag distribution over 0,1,2.. steps")
    assumed_delay_probs: tuple[float, ...] = option((0.3333, 0.3333, 0.3334),
                                                    "lag distribution the learner assumes for credit")
    flip: float = option(0.0, "probability the observer's polarity is flipped")
    stop_episode: int | None = option(None, "observer silent from this episode on; none = never")
    stop_step: int | None = option(None, "observer silent from this global step on; none = never")
    host: str = option("127.0.0.1", "address the router listens on (0.0.0.0 to let other machines join)")
    port: int = option(0, "router port; 0 = pick a free one")
    update_interval: int = option(1, "learner's b: Q and D_global minibatch updates every b steps (paper: 1)")
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
    screen_delay: str = option("uniform:0.2,4", "--teacher web: delay in seconds the learner assumes between a step "
                                                "appearing on a person's screen and their feedback: uniform:LOW,HIGH "
                                                "or a scipy.stats NAME:ARGS (e.g. gamma:2,0.2,0.4)")
    console_port: int = option(0, "--teacher web: the console's web port (0 = pick a free one)")
    webcam: bool = option(False, "--teacher web: also start the perception service for the people's webcams")
    foxglove: int | None = option(None, "also serve the run's channels (as in the log) over Foxglove's WebSocket "
                                        "protocol on this port (services/foxglove; docs/logs.md)")
    foxglove_host: str = option("127.0.0.1", "address the Foxglove bridge serves on")

    def __post_init__(self):
        if self.teacher not in TEACHERS:
            raise ValueError(f"unknown teacher {self.teacher!r}; choose one of {', '.join(TEACHERS)}")
        why = TEACHERS[self.teacher].available()
        if why:
            raise ValueError(f"teacher {self.teacher!r}: {why}")
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
        if not (math.isfinite(self.restart_backoff) and self.restart_backoff >= 0):
            raise ValueError(f"restart-backoff must be >= 0, got {self.restart_backoff}")
        object.__setattr__(self, "delay_probs", parse_probs(self.delay_probs, "delay-probs"))
        object.__setattr__(self, "assumed_delay_probs", parse_probs(self.assumed_delay_probs, "assumed-delay-probs"))


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

    def common(self, service: str) -> dict:
        return dict(run=self.run, connect=self.connect_endpoints, parent_pid=self.parent_pid,
                    stats_out=self.stats_path(service), security=self.cfg.security)


def build_processes(launch: Launch) -> tuple[list[ProcessSpec], list[str]]:
    """The processes of a run, in start order, and the teacher service names."""
    c = launch.cfg
    teachers = TEACHERS[c.teacher].build(launch, c.teacher_id)
    if not teachers:
        raise ValueError(f"teacher kind {c.teacher!r} starts no process")
    teacher_names = [teachers[0].name]
    learner = LearnerConfig(**launch.common("learner"), env=c.env, layout=c.layout, seed=c.seed, algo=c.algo,
                            assumed_delay_probs=c.assumed_delay_probs, update_interval=c.update_interval,
                            weights_every=c.weights_every,
                            end_grace=c.end_grace,
                            wait_teachers=tuple(n.split(".", 1)[1] for n in teacher_names if n.startswith("teacher.")),
                            checkpoint=launch.state_path("learner", ".ckpt"), checkpoint_period=c.checkpoint_period,
                            catchup_log=str(launch.rundir / "session.mcap"), inbox_size=c.learner_inbox,
                            debug_update_sleep=c.debug_update_sleep, screen_delay=c.screen_delay)
    others = ["recorder", "learner"] + [t.name for t in teachers]
    actor = ActorConfig(**launch.common("actor"), env=c.env, layout=c.layout, seed=c.seed, algo=c.algo,
                        episodes=c.episodes, max_steps=c.max_steps, rate=c.rate, max_ahead=c.max_ahead, wait_for=tuple(others),
                        start_timeout=c.start_timeout, max_lag=c.max_lag,
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
    # Whatever a teacher kind built: the run's security file, and a progress file where the service keeps one.
    fields = lambda cfg: {f.name for f in dataclasses.fields(cfg)}  # noqa: E731
    for i, p in enumerate(procs):
        extra = {}
        if "security" in fields(p.config) and getattr(p.config, "security") is None and c.security:
            extra["security"] = c.security
        if "state_file" in fields(p.config) and getattr(p.config, "state_file") is None:
            extra["state_file"] = launch.state_path(p.name)
        if extra:
            procs[i] = dataclasses.replace(p, config=dataclasses.replace(p.config, **extra))
    return procs, teacher_names


# -- processes --------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Child:
    spec: ProcessSpec
    popen: subprocess.Popen
    log_path: Path
    exited_at: float | None = None
    restarts: int = 0  # how many times this service was started again before this process

    @property
    def name(self) -> str:
        return self.spec.name

    def poll(self) -> int | None:
        rc = self.popen.poll()
        if rc is not None and self.exited_at is None:
            self.exited_at = time.monotonic()
        return rc

    def signal_group(self, sig: int) -> None:
        if self.popen.poll() is not None:
            # The leader is gone; its group may still hold children: signal it anyway.
            pass
        try:
            os.killpg(self.popen.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def write_config(path: Path, config: Any) -> None:
    data = config_record(config)
    data.pop("type", None)
    path.write_text(json.dumps(data, indent=2))


def spawn(spec: ProcessSpec, rundir: Path, restarts: int = 0) -> Child:
    cfg_path = rundir / "config" / f"{spec.name}.json"
    if not restarts:
        write_config(cfg_path, spec.config)
    log_path = rundir / "logs" / f"{spec.name}.log"
    log = open(log_path, "a" if restarts else "w")
    if restarts:
        log.write(f"\n----- restart {restarts} at {time.strftime('%H:%M:%S')} -----\n")
        log.flush()
    try:
        popen = subprocess.Popen([sys.executable, "-m", spec.module, "--config", str(cfg_path)], cwd=str(ROOT),
                                 env=child_env(), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
    finally:
        log.close()
    return Child(spec, popen, log_path, restarts=restarts)


def stop_children(children: list[Child], timeout: float = KILL_AFTER) -> None:
    """SIGTERM every process group still alive, wait, then SIGKILL; reap everything."""
    alive = [c for c in children if c.poll() is None]
    for c in alive:
        c.signal_group(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while any(c.poll() is None for c in alive) and time.monotonic() < deadline:
        time.sleep(0.05)
    for c in children:
        c.signal_group(signal.SIGKILL)  # also any grandchild left in the group
        if c.poll() is None:
            try:
                c.popen.wait(2)
            except subprocess.TimeoutExpired:
                pass


def tail(path: Path, n: int = 12) -> str:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join(lines[-n:])


# -- the run ----------------------------------------------------------------------------------------------------

def default_run_name() -> str:
    return time.strftime("live-%Y%m%d-%H%M%S")


class Progress:
    """Progress bar fed by EpisodeSummary messages (received on the router's own session)."""

    def __init__(self, total: int, enabled: bool, label: str):
        from tqdm import tqdm

        self.q: queue.Queue = queue.Queue()
        self.bar = tqdm(total=total, desc=label, unit="ep", file=sys.stderr, disable=not enabled, dynamic_ncols=True)
        self.received = self.credited = 0
        self.count = 0
        self.seen: set[tuple[str, int]] = set()

    def callback(self, sample: Any) -> None:  # zenoh thread: copy and hand over
        self.q.put(sample.payload.to_bytes())

    def pump(self) -> None:
        from common.protocol import EpisodeSummary, ProtocolError

        while True:
            try:
                data = self.q.get_nowait()
            except queue.Empty:
                return
            try:
                ep = EpisodeSummary.decode(data)
            except ProtocolError:
                continue
            if (ep.incarnation, ep.episode) in self.seen:  # re-sent by a restored learner
                continue
            self.seen.add((ep.incarnation, ep.episode))
            self.count += 1
            self.received += ep.feedback_received
            self.credited += ep.feedback_credited
            self.bar.update(1)
            self.bar.set_postfix_str(f"ep {ep.episode} return {ep.return_:.2f} steps {ep.steps} "
                                     f"feedback {self.received} recv/{self.credited} credited "
                                     f"weights v{ep.weights_version}")

    def close(self) -> None:
        self.pump()
        self.bar.close()


class Supervisor:
    """Restarts, their records, and the launcher's foxglove.Log records (on `hitl/<run>/log/launcher`, re-sent
    when the recorder comes back). Liveliness tokens tell when a restarted service is ready again."""

    def __init__(self, cfg: UpConfig, run: str, session: Any):
        from common.protocol import log_key
        from common.transport import MessagePublisher
        from services.common.faults import AliveWatch, ResendRing
        from services.common.runtime import alive_key

        self.cfg, self.run = cfg, run
        self.records: list[dict[str, Any]] = []
        self.restarts: dict[str, int] = collections.Counter()
        self.pending: dict[str, float] = {}  # service -> monotonic time of its restart
        self._alive: dict[str, list[float]] = collections.defaultdict(list)  # service -> wall times of PUTs
        self._lock = threading.Lock()
        self.ring = ResendRing(window=3600.0, max_items=1000)
        self.pub = MessagePublisher(session, log_key(run, "launcher"))
        self.recorder_watch = AliveWatch(session, run, ["recorder"])
        self._sub = session.liveliness().declare_subscriber(alive_key(run), self._on_alive, history=True)

    def _on_alive(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self._alive[str(sample.key_expr).rsplit("/", 1)[-1]].append(time.time())

    def say(self, text: str, level: int = 3) -> None:
        from common.protocol import Log, Time
        from services.common.faults import publish_kept

        print(f"\n[launcher] {text}", file=sys.stderr, flush=True)
        try:
            publish_kept(self.pub, Log(timestamp=Time.from_seconds(time.time()), level=level, message=text[:8000],
                                       name="launcher", file="", line=0), self.ring)
        except Exception as exc:
            print(f"[launcher] (log record not published: {exc})", file=sys.stderr)

    def pump(self) -> None:
        if self.recorder_watch.take() and len(self.ring):
            self.ring.resend()
        with self._lock:
            alive = {k: list(v) for k, v in self._alive.items()}
        for rec in self.records:
            if rec["t_ready"] is None and rec["t_respawned"] is not None:
                after = [t for t in alive.get(rec["service"], []) if t >= rec["t_respawned"]]
                if after:
                    rec["t_ready"] = after[0]
                    rec["recovered_s"] = round(after[0] - rec["t_died"], 3)
                    self.say(f"{rec['service']} is back: ready {rec['recovered_s']:.2f} s after it died", 2)

    def can_restart(self, name: str) -> bool:
        return self.restarts[name] < self.cfg.restart_limit

    def died(self, child: Child, rc: int) -> None:
        name = child.name
        k = self.restarts[name]
        delay = min(8.0, self.cfg.restart_backoff * 2 ** k)
        self.restarts[name] += 1
        self.pending[name] = time.monotonic() + delay
        how = f"signal {signal.Signals(-rc).name}" if rc < 0 and -rc in signal.Signals._value2member_map_ else f"code {rc}"
        self.records.append({"service": name, "restart": k + 1, "exit": rc, "how": how, "t_died": time.time(),
                             "t_respawned": None, "t_ready": None, "recovered_s": None,
                             "pid": child.popen.pid})
        self.say(f"{name} died ({how}); restarting in {delay:.1f} s (restart {k + 1} of {self.cfg.restart_limit}); "
                 f"last lines of {child.log_path}:\n{tail(child.log_path, 5)}", 4)

    def respawned(self, child: Child) -> None:
        for rec in reversed(self.records):
            if rec["service"] == child.name and rec["t_respawned"] is None:
                rec["t_respawned"] = time.time()
                rec["new_pid"] = child.popen.pid
                break

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._sub.undeclare()
        self.recorder_watch.close()
        self.pub.close()


def up(cfg: UpConfig) -> int:
    import zenoh

    from common.protocol import episode_key
    from common.transport import free_port, router_config, tcp_endpoint

    run = cfg.run or default_run_name()
    ServiceConfig(run=run)  # validates the name
    rundir = Path(cfg.out) / run
    if (rundir / "session.mcap").exists():
        print(f"error: {rundir}/session.mcap exists; choose another --run", file=sys.stderr)
        return 2
    for sub in ("config", "logs", "stats", "state"):
        (rundir / sub).mkdir(parents=True, exist_ok=True)
    port = cfg.port or free_port(cfg.host)
    if cfg.security:
        from common.security import load_security, router_config_for, tls_endpoint

        security = load_security(cfg.security)
        endpoint = tls_endpoint(port, cfg.host)
        router_cfg = router_config_for(security, port, host=cfg.host)
    else:
        endpoint = tcp_endpoint(port, cfg.host)
        router_cfg = router_config(endpoint)
    launch = Launch(cfg, run, rundir, endpoint)
    procs, teacher_names = build_processes(launch)
    run_record = {"launcher": {**config_record(cfg), "run": run, "endpoint": endpoint},
                  "services": {p.name: config_record(p.config) for p in procs}}
    (rundir / "config" / "run.json").write_text(json.dumps(run_record, indent=2))

    interrupts = {"n": 0}

    def on_sigint(signum, frame):
        interrupts["n"] += 1

    old_int = signal.signal(signal.SIGINT, on_sigint)
    old_term = signal.signal(signal.SIGTERM, on_sigint)
    children: list[Child] = []  # the current process of each service
    everyone: list[Child] = []  # every process started (for the exit history and the final reaping)
    t_start = time.time()
    outcome = "ok"
    session = zenoh.open(router_cfg)
    print(f"zenoh endpoint: {endpoint}  (run {run}; join with --connect {endpoint} --run {run})",
          file=sys.stderr, flush=True)
    print(f"run directory: {rundir}", file=sys.stderr, flush=True)
    for line in getattr(launch, "banners", []):  # e.g. the console's address (--teacher web)
        print(line, file=sys.stderr, flush=True)
    progress = Progress(cfg.episodes, cfg.progress, f"{cfg.algo} on {cfg.env}")
    sup = Supervisor(cfg, run, session)
    try:
        sub = session.declare_subscriber(episode_key(run), progress.callback)
        for spec in procs:
            children.append(spawn(spec, rundir))
        everyone.extend(children)
        by_name = {c.name: c for c in children}
        graceful_deadline: float | None = None
        asked = 0
        handled: set[int] = set()  # pids whose death was dealt with
        while True:
            progress.pump()
            sup.pump()
            codes = {c.name: c.poll() for c in children}
            for c in children:
                rc = codes[c.name]
                if rc in (None, 0) or c.popen.pid in handled:
                    continue
                handled.add(c.popen.pid)
                if interrupts["n"] == 0 and outcome == "ok" and sup.can_restart(c.name):
                    sup.died(c, rc)
                elif outcome == "ok":
                    outcome = "failed"
                    why = "" if interrupts["n"] else f" ({sup.restarts[c.name]} restarts already)"
                    print(f"\nerror: {c.name} exited with code {rc}{why}; last lines of {c.log_path}:\n"
                          f"{tail(c.log_path)}", file=sys.stderr)
            for name, due in list(sup.pending.items()):
                if outcome != "ok" or interrupts["n"]:
                    del sup.pending[name]
                elif time.monotonic() >= due:
                    old = by_name[name]
                    new = spawn(old.spec, rundir, restarts=old.restarts + 1)
                    children[children.index(old)] = new
                    everyone.append(new)
                    by_name[name] = new
                    del sup.pending[name]
                    sup.respawned(new)
                    codes[name] = None
                    if graceful_deadline is not None:  # let it finish what it restarted for
                        graceful_deadline = max(graceful_deadline, time.monotonic() + cfg.stop_timeout)
            actor = by_name["actor"]
            if all(rc is not None for rc in codes.values()) and not sup.pending:
                break
            if interrupts["n"] > asked:
                asked = interrupts["n"]
                if asked == 1:
                    if outcome == "ok":
                        outcome = "interrupted"
                    print("\nstopping (Ctrl-C again to kill)...", file=sys.stderr, flush=True)
                    actor.signal_group(signal.SIGTERM)
                    graceful_deadline = time.monotonic() + cfg.stop_timeout
                else:
                    stop_children(children)
            if outcome == "failed" and graceful_deadline is None:
                actor.signal_group(signal.SIGTERM)
                graceful_deadline = time.monotonic() + min(cfg.stop_timeout, 5.0)
            if codes["actor"] == 0 and graceful_deadline is None:
                graceful_deadline = time.monotonic() + cfg.stop_timeout
            if graceful_deadline is not None and time.monotonic() > graceful_deadline:
                stragglers = [c.name for c in children if c.poll() is None]
                print(f"\nterminating {', '.join(stragglers)} (still running {cfg.stop_timeout:.0f} s after the end)",
                      file=sys.stderr, flush=True)
                stop_children(children)
                if outcome == "ok":
                    outcome = "timeout"
            time.sleep(0.05)
        sub.undeclare()
        sup.pump()
    finally:
        stop_children(everyone)
        progress.close()
        sup.close()
        session.close()
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
    wall = time.time() - t_start
    return finish(cfg, run, rundir, endpoint, children, outcome, wall, sup.records, everyone)


def finish(cfg: UpConfig, run: str, rundir: Path, endpoint: str, children: list[Child], outcome: str,
           wall: float, restarts: list[dict] | None = None, everyone: list[Child] | None = None) -> int:
    from services.replay.summary import format_summary, plot_summary, summarize

    log = rundir / "session.mcap"
    summary: dict[str, Any] = {"run": run, "outcome": outcome, "endpoint": endpoint, "wall_s": round(wall, 3),
                               "exit_codes": {c.name: c.popen.returncode for c in children},
                               "restarts": restarts or [],
                               "exit_history": [{"service": c.name, "pid": c.popen.pid, "exit": c.popen.returncode}
                                                for c in (everyone or children)]}
    if log.exists():
        try:
            summary.update(summarize(log))
            summary["outcome"] = outcome
            summary["restarts"] = restarts or []
            plot_summary(summary, rundir / "learning_curve.png",
                         f"{cfg.algo} on {cfg.env} (live, teacher {cfg.teacher}, seed {cfg.seed})")
        except Exception as exc:  # a damaged log still gets a summary.json saying so
            summary["summary_error"] = f"{type(exc).__name__}: {exc}"
    stats = {}
    for p in sorted((rundir / "stats").glob("*.json")):
        try:
            stats[p.stem] = json.loads(p.read_text())
        except (OSError, ValueError):
            pass
    summary["latency_ms"] = latency_table(stats)
    (rundir / "summary.json").write_text(json.dumps(summary, indent=2))
    if "returns" in summary:
        print(format_summary(summary), file=sys.stderr)
    print(f"wrote {rundir}/session.mcap, summary.json, learning_curve.png ({outcome}, {wall:.1f} s)", file=sys.stderr)
    return {"ok": 0, "interrupted": 130}.get(outcome, 1)


def percentiles(values: list[float]) -> dict[str, float] | None:
    import numpy as np

    if not values:
        return None
    a = np.asarray(values, dtype=float) * 1e3
    return {"n": int(a.size), "p50": round(float(np.percentile(a, 50)), 3), "p99": round(float(np.percentile(a, 99)), 3),
            "max": round(float(a.max()), 3)}


def latency_table(stats: dict[str, dict]) -> dict[str, Any]:
    out = {}
    learner = stats.get("learner", {}).get("samples", {})
    actor = stats.get("actor", {}).get("samples", {})
    out["feedback_to_h_update"] = percentiles(learner.get("feedback_to_h_s", []))
    out["weights_publish_to_adoption"] = percentiles(actor.get("adopt_latency_s", []))
    return out
