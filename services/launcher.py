"""`python -m services up`: a whole live run on this machine.

Starts an embedded Zenoh router (this process's own session in router mode, listening on HOST:PORT, no
multicast scouting), spawns one process per service (recorder, learner, the teacher's processes, actor; each
in its own process group, each told to exit if this process disappears), shows a progress bar fed by the
learner's EpisodeSummary messages, and stops everything at the end or on Ctrl-C: the actor is asked to stop
(SIGTERM), the others then finish on their own (teacher -> learner -> recorder); whatever is still running
after `stop_timeout` s gets SIGTERM, then SIGKILL 3 s later. Leaves in OUT/RUN/: session.mcap,
summary.json, learning_curve.png, config/<service>.json, logs/<service>.log, stats/<service>.json.
"""
from __future__ import annotations

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
from services.common.config import (ActorConfig, LearnerConfig, RecorderConfig, ServiceConfig,
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

    def __post_init__(self):
        if self.teacher not in TEACHERS:
            raise ValueError(f"unknown teacher {self.teacher!r}; choose one of {', '.join(TEACHERS)}")
        why = TEACHERS[self.teacher].available()
        if why:
            raise ValueError(f"teacher {self.teacher!r}: {why}")
        if self.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {self.episodes}")
        if not (math.isfinite(self.rate) and self.rate >= 0):
            raise ValueError(f"rate must be >= 0, got {self.rate}")
        if not 0 <= self.port < 65536:
            raise ValueError(f"port must be in 0..65535, got {self.port}")
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

    def common(self, service: str) -> dict:
        return dict(run=self.run, connect=self.connect_endpoints, parent_pid=self.parent_pid,
                    stats_out=self.stats_path(service))


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
                            wait_teachers=tuple(n.split(".", 1)[1] for n in teacher_names if n.startswith("teacher.")))
    others = ["recorder", "learner"] + [t.name for t in teachers]
    actor = ActorConfig(**launch.common("actor"), env=c.env, layout=c.layout, seed=c.seed, algo=c.algo,
                        episodes=c.episodes, max_steps=c.max_steps, rate=c.rate, max_ahead=c.max_ahead, wait_for=tuple(others),
                        start_timeout=c.start_timeout)
    recorder = RecorderConfig(**launch.common("recorder"), out=str(launch.rundir / "session.mcap"),
                              run_config=str(launch.rundir / "config" / "run.json"),
                              stop_when=tuple(["actor", "learner"] + teacher_names))
    procs = [ProcessSpec("recorder", "services.recorder", recorder),
             ProcessSpec("learner", "services.learner", learner), *teachers,
             ProcessSpec("actor", "services.actor", actor)]
    return procs, teacher_names


# -- processes --------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Child:
    spec: ProcessSpec
    popen: subprocess.Popen
    log_path: Path
    exited_at: float | None = None

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


def spawn(spec: ProcessSpec, rundir: Path) -> Child:
    cfg_path = rundir / "config" / f"{spec.name}.json"
    write_config(cfg_path, spec.config)
    log_path = rundir / "logs" / f"{spec.name}.log"
    log = open(log_path, "w")
    try:
        popen = subprocess.Popen([sys.executable, "-m", spec.module, "--config", str(cfg_path)], cwd=str(ROOT),
                                 env=child_env(), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
    finally:
        log.close()
    return Child(spec, popen, log_path)


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
    for sub in ("config", "logs", "stats"):
        (rundir / sub).mkdir(parents=True, exist_ok=True)
    port = cfg.port or free_port(cfg.host)
    endpoint = tcp_endpoint(port, cfg.host)
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
    children: list[Child] = []
    t_start = time.time()
    outcome = "ok"
    session = zenoh.open(router_config(endpoint))
    print(f"zenoh endpoint: {endpoint}  (run {run}; join with --connect {endpoint} --run {run})",
          file=sys.stderr, flush=True)
    print(f"run directory: {rundir}", file=sys.stderr, flush=True)
    progress = Progress(cfg.episodes, cfg.progress, f"{cfg.algo} on {cfg.env}")
    try:
        sub = session.declare_subscriber(episode_key(run), progress.callback)
        for spec in procs:
            children.append(spawn(spec, rundir))
        by_name = {c.name: c for c in children}
        actor = by_name["actor"]
        graceful_deadline: float | None = None
        asked = 0
        while True:
            progress.pump()
            codes = {c.name: c.poll() for c in children}
            failed = [n for n, rc in codes.items() if rc not in (None, 0)]
            if failed and outcome == "ok":
                outcome = "failed"
                for n in failed:
                    print(f"\nerror: {n} exited with code {codes[n]}; last lines of {by_name[n].log_path}:\n"
                          f"{tail(by_name[n].log_path)}", file=sys.stderr)
            if all(rc is not None for rc in codes.values()):
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
            if codes["actor"] is not None and graceful_deadline is None:
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
    finally:
        stop_children(children)
        progress.close()
        session.close()
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
    wall = time.time() - t_start
    return finish(cfg, run, rundir, endpoint, children, outcome, wall)


def finish(cfg: UpConfig, run: str, rundir: Path, endpoint: str, children: list[Child], outcome: str,
           wall: float) -> int:
    from services.replay.summary import format_summary, plot_summary, summarize

    log = rundir / "session.mcap"
    summary: dict[str, Any] = {"run": run, "outcome": outcome, "endpoint": endpoint, "wall_s": round(wall, 3),
                               "exit_codes": {c.name: c.popen.returncode for c in children}}
    if log.exists():
        try:
            summary.update(summarize(log))
            summary["outcome"] = outcome
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
