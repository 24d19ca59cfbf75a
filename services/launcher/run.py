"""`up()`: one live run from start to summary (the loop that starts, watches, restarts and stops the services)."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.config import config_record
from services.common.config import ServiceConfig
from services.common.runtime import TERMINAL_EXIT
from services.common.statefiles import atomic_write
from services.launcher.children import Child, spawn, stop_children, tail
from services.launcher.config import Launch, UpConfig, build_processes
from services.launcher.report import Progress, finish
from services.launcher.rundir import RunDir, RunDirError, default_run_name, describe, is_disk_full
from services.launcher.supervise import Supervisor
from services.common.runtime import set_from_handler
from services.launcher.unfinished import finish_unfinished_runs

DISK_CHECK_PERIOD = 1.0  # s between free-space checks
STATUS_PERIOD = 5.0  # s between the launcher's own statuses (as the services' default status-period)
DISK_FULL_TEXT = "No space left on device"


def router_settings(cfg: UpConfig, port: int) -> tuple[str, Any]:
    """The embedded router's endpoint and zenoh config (the secured one with `security`)."""
    from common.wire.transport import router_config, tcp_endpoint

    if cfg.security:
        from common.security import load_security, router_config_for, tls_endpoint

        return tls_endpoint(port, cfg.host), router_config_for(load_security(cfg.security), port, host=cfg.host)
    endpoint = tcp_endpoint(port, cfg.host)
    return endpoint, router_config(endpoint)


class Run:
    """The state of one run while the launcher watches it."""

    def __init__(self, cfg: UpConfig, run: str, rundir: RunDir, endpoint: str):
        self.cfg, self.run, self.rundir, self.endpoint = cfg, run, rundir, endpoint
        self.children: list[Child] = []  # the current process of each service
        self.everyone: list[Child] = []  # every process started (exit history, final reaping)
        self.by_name: dict[str, Child] = {}
        self.handled: set[int] = set()  # pids whose death was dealt with
        self.outcome = "ok"
        self.error: str | None = None
        self.interrupts = 0
        self.asked = 0
        self.graceful_deadline: float | None = None
        self.next_disk_check = 0.0
        self.next_status = 0.0
        self.sup: Supervisor  # set once the router session is open
        self.status_pub: Any = None
        self.statuses: Any = None
        self.status_sub: Any = None

    # -- the launcher's own status: 'stopping' tells every service the run is ending (common/wire/auth.py signs it) --
    def announce(self, state: str) -> None:
        from common.protocol import ServiceStatus

        if self.status_pub is None:
            return
        try:
            self.status_pub.put(
                ServiceStatus(
                    run=self.run,
                    service="launcher",
                    pid=os.getpid(),
                    state=state,
                    t=time.time(),
                    counters={},
                    incarnation=f"launcher-{os.getpid()}",
                )
            )
        except Exception as exc:  # never let a status take the launcher down
            print(f"[launcher] (status not published: {exc})", file=sys.stderr)

    def end(self, outcome: str | None = None, error: str | None = None, grace: float | None = None) -> None:
        """Begin a clean stop: say the run is ending, ask the actor to stop; the others follow."""
        if outcome and self.outcome == "ok":
            self.outcome = outcome
        if error and self.error is None:
            self.error = error
        if self.graceful_deadline is None:
            self.announce("stopping")
            self.by_name["actor"].signal_group(signal.SIGTERM)
            self.graceful_deadline = time.monotonic() + (self.cfg.stop_timeout if grace is None else grace)

    def disk_full(self, why: str) -> None:
        if self.outcome != "disk_full":
            self.end("disk_full", f"disk full: {why}; stopping the run", grace=min(self.cfg.stop_timeout, 5.0))

    # -- one pass of the loop ---------------------------------------------------------------------------------
    def deaths(self) -> None:
        for c in self.children:
            rc = c.poll()
            if rc in (None, 0) or c.popen.pid in self.handled:
                continue
            self.handled.add(c.popen.pid)
            if DISK_FULL_TEXT in tail(c.log_path, 40) or self.rundir.free_mb() < self.cfg.min_free_mb:
                self.disk_full(
                    f"{c.name} exited with code {rc} ({self.rundir.free_mb():.1f} MiB free under {self.rundir.path})"
                )
            elif rc == TERMINAL_EXIT:
                self.terminal(c)
            elif self.interrupts == 0 and self.outcome == "ok" and self.sup.can_restart(c.name):
                self.sup.died(c, rc)
            elif self.outcome == "ok":
                self.outcome = "failed"
                why = "" if self.interrupts else f" ({self.sup.restarts[c.name]} restarts already)"
                print(
                    f"\nerror: {c.name} exited with code {rc}{why}; last lines of {c.log_path}:\n{tail(c.log_path)}",
                    file=sys.stderr,
                )

    def terminal(self, c: Child) -> None:
        """A service stopped by an error a restart would repeat (a teacher rule that raises): end the run with it."""
        errors = [line for line in tail(c.log_path, 40).splitlines() if line.startswith("error: ")]
        why = errors[-1][len("error: ") :] if errors else f"exited with code {TERMINAL_EXIT}"
        print(
            f"\nerror: {c.name}: {why}; stopping the run (no restart: it would fail the same way)",
            file=sys.stderr,
            flush=True,
        )
        self.end("failed", f"{c.name}: {why}", grace=min(self.cfg.stop_timeout, 5.0))

    def respawns(self) -> None:
        for name, due in list(self.sup.pending.items()):
            if self.outcome != "ok" or self.interrupts:
                del self.sup.pending[name]
            elif time.monotonic() >= due:
                old = self.by_name[name]
                new = spawn(old.spec, self.rundir.path, restarts=old.restarts + 1)
                self.children[self.children.index(old)] = new
                self.everyone.append(new)
                self.by_name[name] = new
                del self.sup.pending[name]
                self.sup.respawned(new)
                if self.graceful_deadline is not None:  # let it finish what it restarted for
                    self.graceful_deadline = max(self.graceful_deadline, time.monotonic() + self.cfg.stop_timeout)

    def hangs(self) -> None:
        if self.outcome != "ok" or self.interrupts:
            return
        for child, why in self.sup.hung(self.children, self.statuses):
            self.sup.kill_hung(child, why)  # its death is then handled (and restarted) like any other

    def disk(self) -> None:
        if time.monotonic() < self.next_disk_check:
            return
        self.next_disk_check = time.monotonic() + DISK_CHECK_PERIOD
        free = self.rundir.free_mb()
        if free < self.cfg.min_free_mb:
            self.disk_full(
                f"{free:.1f} MiB free under {self.rundir.path} (less than --min-free-mb {self.cfg.min_free_mb:g})"
            )

    def signals(self) -> None:
        if self.interrupts <= self.asked:
            return
        self.asked = self.interrupts
        if self.asked == 1:
            print("\nstopping (Ctrl-C again to kill)...", file=sys.stderr, flush=True)
            self.end("interrupted")
        else:
            stop_children(self.children)

    def ending(self) -> bool:
        """True when every service has exited and nothing is waiting to restart."""
        codes = {c.name: c.poll() for c in self.children}
        if all(rc is not None for rc in codes.values()) and not self.sup.pending:
            return True
        if self.outcome == "failed" and self.graceful_deadline is None:
            self.end(grace=min(self.cfg.stop_timeout, 5.0))
        if codes["actor"] == 0 and self.graceful_deadline is None:
            self.announce("stopping")  # the actor finished the run: stragglers stopped later end 'stopped'
            self.graceful_deadline = time.monotonic() + self.cfg.stop_timeout
        if self.graceful_deadline is not None and time.monotonic() > self.graceful_deadline:
            stragglers = [c.name for c in self.children if c.poll() is None]
            print(
                f"\nterminating {', '.join(stragglers)} (still running {self.cfg.stop_timeout:.0f} s after the end)",
                file=sys.stderr,
                flush=True,
            )
            self.announce("stopping")
            stop_children(self.children)
            if self.outcome == "ok":
                self.outcome = "timeout"
        return False

    def step(self) -> bool:
        """One pass; True when the run is over."""
        if time.monotonic() >= self.next_status and self.graceful_deadline is None:
            self.next_status = time.monotonic() + STATUS_PERIOD
            self.announce("ready")  # services know a launcher supervises them (a stray SIGTERM is then a death)
        try:
            self.sup.pump()
            self.deaths()
            self.respawns()
            self.hangs()
            self.disk()
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            self.disk_full(describe(exc))
        self.signals()
        return self.ending()


def prepare(cfg: UpConfig) -> tuple[str, RunDir, Launch, list, Any]:
    """Name, the router's session (listening: its port is the children's), directory (locked), credentials,
    processes and the run record. Raises RunDirError."""
    from common.wire.transport import PortInUse, open_listening

    run = cfg.run or default_run_name()
    ServiceConfig(run=run)  # validates the name
    try:
        session, port = open_listening(lambda p: router_settings(cfg, p)[1], cfg.port, cfg.host)
    except PortInUse as exc:
        raise RunDirError(str(exc)) from None
    try:
        return (run, *record_run(cfg, run, router_settings(cfg, port)[0]), session)
    except BaseException:
        session.close()  # an unclosed session keeps the launcher from exiting
        raise


def record_run(cfg: UpConfig, run: str, endpoint: str) -> tuple[RunDir, Launch, list]:
    rundir = RunDir(cfg.out, run)
    rundir.open()
    launch = Launch(cfg, run, rundir.path, endpoint)
    procs, _ = build_processes(launch)
    try:
        rundir.make_credentials(run, ["launcher"] + [p.name for p in procs])
        run_record = {
            "launcher": {**config_record(cfg), "run": run, "endpoint": endpoint},
            "services": {p.name: config_record(p.config) for p in procs},
        }
        # Whole or not at all: tools and tests read it as soon as it exists (a reader once met it empty).
        atomic_write(rundir.path / "config" / "run.json", json.dumps(run_record, indent=2).encode())
    except OSError as exc:
        raise RunDirError(f"cannot write the run directory {rundir.path}: {describe(exc)}") from None
    return rundir, launch, procs


def check_task_and_agent(cfg: UpConfig) -> None:
    """The env and the agent's networks can be built: else one line now, not a dying service later."""
    from common.agents.config import agent_for, resolve_network
    from common.envs import make_env, obs_shape

    env = make_env(cfg.env, cfg.layout, cfg.task.teacher_rule)[0]
    agent = agent_for(cfg.algo, cfg.agent)  # (built in UpConfig's __post_init__: the same object)
    if resolve_network(agent.network, obs_shape(env)) != "mlp":  # the numpy MLP has nothing to check (no torch)
        from common.agents.torch_agent import check_agent

        check_agent(agent, env)


def up(cfg: UpConfig) -> int:
    try:
        check_task_and_agent(cfg)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finish_unfinished_runs(cfg.out)  # runs in this --out whose launcher was killed get their summary.json
    try:
        run, rundir, launch, procs, session = prepare(cfg)
    except RunDirError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        return watch(cfg, run, rundir, launch, procs, session)
    finally:
        rundir.close()


def attach_launcher(r: Run, session: Any) -> None:
    """The launcher on the router's session: signing as `launcher` (its credential), its status publisher, and
    the services' statuses."""
    from common.wire.auth import Auth, load_credential
    from common.protocol import KEYS, status_key
    from common.wire.transport import MessagePublisher, set_default_auth, subscribe

    set_default_auth(Auth(load_credential(r.rundir.path / "credentials" / "launcher.json", r.run, "launcher")))
    r.status_pub = MessagePublisher(session, status_key(r.run, "launcher"), congestion="block")
    r.status_sub, r.statuses = subscribe(session, KEYS["status"].wildcard(r.run), maxsize=4096, policy="drop_oldest")


def watch(cfg: UpConfig, run: str, rundir: RunDir, launch: Launch, procs: list, session: Any) -> int:
    """Supervise the run on the router's `session` (closed here, whatever happens) until it ends."""
    r = Run(cfg, run, rundir, launch.endpoint)

    def on_signal(signum, frame):
        r.interrupts += 1
        if getattr(r, "sup", None) is not None:
            set_from_handler(r.sup.wake)  # the loop's pass now, not after its rest

    old_int, old_term = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    t_start = time.time()
    try:
        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        attach_launcher(r, session)
        return _supervise(cfg, run, rundir, launch, procs, r, session, t_start)
    finally:
        session.close()
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def print_when_listening(waiting: list[tuple[str, str, Callable[[int], str]]]) -> list:
    """Print each (host, port file, line) whose server wrote its port and accepts connections there now; the rest
    wait for the next call."""
    import socket

    left = []
    for host, port_file, line in waiting:
        try:
            port = int(Path(port_file).read_text())
            socket.create_connection((host, port), timeout=0.2).close()
        except (OSError, ValueError):  # (not written yet, or not listening yet)
            left.append((host, port_file, line))
            continue
        print(line(port), file=sys.stderr, flush=True)
    return left


def _supervise(
    cfg: UpConfig, run: str, rundir: RunDir, launch: Launch, procs: list, r: Run, session: Any, t_start: float
) -> int:
    """Announce the run, start the children and pump until the run ends; always stops what it started."""
    print(
        f"zenoh endpoint: {launch.endpoint}  (run {run}; join with --connect {launch.endpoint} --run {run})",
        file=sys.stderr,
        flush=True,
    )
    print(f"run directory: {rundir.path}", file=sys.stderr, flush=True)
    progress = Progress(cfg.episodes, cfg.progress, f"{cfg.algo} on {cfg.env}")
    r.sup = Supervisor(cfg, run, session)
    try:
        sub = progress.subscribe(session, run)
        r.announce("ready")
        try:
            for spec in procs:
                r.children.append(spawn(spec, rundir.path))
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            r.outcome, r.error = "disk_full", f"disk full: {describe(exc)}; stopping the run"
        r.everyone.extend(r.children)
        r.by_name = {c.name: c for c in r.children}
        waiting = list(launch.listening_banners)
        while len(r.children) == len(procs):
            waiting = print_when_listening(waiting)
            progress.pump()
            if r.step():
                break
            r.sup.rest(busy=bool(waiting) or r.graceful_deadline is not None or r.interrupts > 0)
        sub.undeclare()
        r.sup.pump()
    finally:
        r.announce("stopping")
        stop_children(r.everyone)
        progress.close()
        r.sup.close()
        r.status_pub.close()
    return finish(
        cfg,
        run,
        rundir,
        launch.endpoint,
        r.children,
        r.outcome,
        time.time() - t_start,
        r.sup.records,
        r.everyone,
        r.error,
    )
