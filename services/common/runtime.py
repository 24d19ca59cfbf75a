"""What every service process does besides its job: stop on SIGTERM/SIGINT or when its launcher is gone,
open a Zenoh client session that always closes, announce itself (liveliness token
`hitl/<run>/alive/<service>` once ready, ServiceStatus on `hitl/<run>/status/<service>`), count things,
and write its final counters to a JSON file.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import json
import os
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING, Any
from collections.abc import Callable, Iterator

from services.common.statefiles import atomic_write

if TYPE_CHECKING:
    from common.wire.delivery import Inbox
    from common.wire.transport import MessagePublisher
from common.protocol import ServiceStatus, alive_key, incarnation_alive_key, status_key, teacher_id_of, validate_name
from services.common.process import TERMINAL_EXIT, TerminalError, set_from_handler, wait_for_exit, new_incarnation

HARD_EXIT_AFTER = 5.0  # s a service gets to stop cleanly once its launcher is gone
MAX_SAMPLES = 200_000  # latency samples kept per kind


class ServiceRuntime:
    """Life cycle of one service process. Use::

    rt = ServiceRuntime("learner", config)
    with rt.session() as session:
        ...declare subscribers...
        rt.ready()                   # liveliness token + status "ready"
        while not rt.stop.is_set(): ...; rt.tick()
    rt.finish()                      # final status was sent in session(); stats file written
    """

    def __init__(self, name: str, config: Any, *, install_signals: bool = True, process_default: bool = True):
        validate_name(name, "service")
        self.name = name
        self.config = config
        self.stop = threading.Event()
        self.counters: collections.Counter[str] = collections.Counter()
        # Latency samples: the newest MAX_SAMPLES of each (bounded, however long the run).
        self.samples: dict[str, collections.deque] = collections.defaultdict(
            lambda: collections.deque(maxlen=MAX_SAMPLES)
        )
        self.state = "starting"
        self.incarnation = new_incarnation(name)
        self.failed = False  # set by a service that ends without finishing its part of the run
        self.signalled = False
        self.final_state: str | None = None
        self._run_end: Inbox | None = None  # inbox of the launcher's status: 'stopping' means the run is ending
        self._supervised = self._run_ending = False
        _CURRENT[0] = self
        self.auth = load_auth(name, config, self.incarnation, process_default)
        self._session: Any = None  # the open zenoh.Session (zenoh is imported only where a session is opened)
        self._status_pub: MessagePublisher | None = None
        self._log_pub: MessagePublisher | None = None
        self._token: Any = None  # zenoh liveliness tokens
        self._inc_token: Any = None
        self._recorder_sub: Any = None  # the recorder's liveliness: a status for each recorder that comes
        self._recorder_came = threading.Event()
        self._last_status = 0.0
        self._extra_counters: Callable[[], dict[str, int]] | None = None
        self._cpu_at_ready: float | None = None
        if install_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, self._on_signal)
        parent = getattr(config, "parent_pid", None)
        # Started by a launcher (it passes its pid): supervised from the start, not only from its first status
        # (a stray SIGTERM in the first second, before that status came, was taken for the end of the run).
        self._supervised = bool(parent)
        if parent:
            threading.Thread(target=self._watch_parent, args=(int(parent),), name="parent-watch", daemon=True).start()

    # -- stopping ----------------------------------------------------------------------------------------------
    def _on_signal(self, signum, _frame) -> None:
        self.counters[f"signal_{signal.Signals(signum).name}"] += 1
        self.signalled = True
        set_from_handler(self.stop)

    def _watch_parent(self, pid: int) -> None:
        """The launcher is gone (e.g. SIGKILLed): stop, and if a clean stop does not finish within
        HARD_EXIT_AFTER s (zenoh.open retrying a dead router cannot be interrupted), exit hard."""
        wait_for_exit(pid)
        self.log(f"parent {pid} is gone; stopping")
        self.counters["parent_gone"] += 1
        self.stop.set()
        time.sleep(HARD_EXIT_AFTER)
        self.log(f"still running {HARD_EXIT_AFTER} s after the parent left; exiting hard")
        os._exit(3)

    def log(self, text: str) -> None:
        print(f"[{self.name}] {text}", file=sys.stderr, flush=True)

    # -- session -----------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def session(self) -> Iterator[Any]:
        """A client session to the configured router(s); on exit: final status 'stopped', token dropped,
        a short linger so BLOCK publishers' queues drain, then close."""
        from common.wire.transport import MessagePublisher, open_session, subscribe

        cfg = self.config
        with open_session(self.zenoh_config()) as session:
            self._session = session
            status_pub = MessagePublisher(session, status_key(cfg.run, self.name), congestion="block")
            self._status_pub = status_pub
            run_end_sub, self._run_end = subscribe(session, status_key(cfg.run, "launcher"), maxsize=4)
            ok = False
            try:
                self.publish_status("starting")
                yield session
                ok = True
            finally:
                self.final_state = "stopped" if ok and self._finished_its_part() else "failed"
                with contextlib.suppress(Exception):
                    self.publish_status(self.final_state)
                with contextlib.suppress(Exception):
                    run_end_sub.undeclare()
                for token in (self._recorder_sub, self._token, self._inc_token):
                    if token is not None:
                        with contextlib.suppress(Exception):
                            token.undeclare()
                time.sleep(0.2)  # let the transmission queues empty before the session closes
                status_pub.close()
                if self._log_pub is not None:
                    self._log_pub.close()
                    self._log_pub = None
                self._session = None

    def _finished_its_part(self) -> bool:
        """'stopped' ends the run for whoever waits on this service; 'failed' does not (the launcher restarts it).
        Stopped by a signal while a launcher supervises the run (its authenticated statuses come every second):
        stopped only if the launcher said the run is ending ('stopping'); anybody else's SIGTERM is a death like
        any other. Without a launcher, a signal is how a person stops a service."""
        if self.failed:
            return False
        if not self.signalled or self.counters["parent_gone"]:
            return True
        deadline = time.monotonic() + 1.0  # the launcher says so just before it signals
        while True:
            ending = self.run_is_ending()
            if ending or not self._supervised or time.monotonic() > deadline:
                return ending or not self._supervised
            time.sleep(0.02)

    def run_is_ending(self) -> bool:
        """True once the launcher has announced (authenticated status 'stopping' or 'stopped') the end of the run."""
        if self._run_end is None:
            return False
        for item in self._run_end.drain():
            try:
                st = item.decode()
            except Exception:
                continue
            self._supervised = True
            if st.state in ("stopping", "stopped"):
                self._run_ending = True
        return self._run_ending

    def zenoh_config(self) -> Any:
        """A plain loopback client of `connect`, or with `security` the secured client of this service's
        identity (role from the service name: `teacher.<id>` is teacher `<id>`)."""
        from common.wire.transport import client_config

        cfg = self.config
        security = getattr(cfg, "security", None)
        if not security:
            return client_config(*cfg.connect, connect_timeout=cfg.connect_timeout)
        from common.security import client_config_for, load_security

        sec = load_security(security)
        endpoint = next((e for e in cfg.connect if e.startswith("tls/")), None)
        if teacher_id_of(self.name):
            return client_config_for(
                sec, "teacher", endpoint, teacher=self.name.split(".", 1)[1], connect_timeout=cfg.connect_timeout
            )
        role = self.name.split(".", 1)[0]
        return client_config_for(sec, role, endpoint, connect_timeout=cfg.connect_timeout)

    def event(self, text: str, level: int = 2) -> None:
        """Say it on stderr and as a foxglove.Log on `hitl/<run>/log/<service>` (recorded with the run)."""
        self.log(text)
        if self._session is None:
            return
        from common.protocol import Log, Time, log_key
        from common.wire.transport import MessagePublisher

        try:
            if self._log_pub is None:
                self._log_pub = MessagePublisher(self._session, log_key(self.config.run, self.name))
            self._log_pub.put(
                Log(
                    timestamp=Time.from_seconds(time.time()),
                    level=level,
                    message=text[:8000],
                    name=self.name,
                    file="",
                    line=0,
                )
            )
        except Exception as exc:  # a log line must never take a service down
            self.log(f"(could not publish the log record: {exc})")

    def ready(self) -> None:
        """Subscribers are declared: announce liveliness and state 'ready'."""
        self._token = self._session.liveliness().declare_token(alive_key(self.config.run, self.name))
        # Announces this incarnation to receivers that accept inputs only from announced ones (services/common/gate.py).
        self._inc_token = self._session.liveliness().declare_token(
            incarnation_alive_key(self.config.run, self.name, self.incarnation)
        )
        self._cpu_at_ready = time.process_time()
        # What start-up built (modules, the agent, Zenoh's objects) lives as long as the service: frozen, a full
        # collection no longer walks it. Unfrozen, the learner's full collections took 20-70 ms every 2 s at 250
        # steps/s, each a stall of every step behind it (docs/notes/2026-11-28-full-speed.md).
        gc.collect()
        gc.freeze()
        self.publish_status("ready")
        if self.name != "recorder":  # (a recorder that starts after this one missed 'ready': tick() says it again)
            self._recorder_sub = self._session.liveliness().declare_subscriber(
                alive_key(self.config.run, "recorder"), self._on_recorder, history=True
            )

    def _on_recorder(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.PUT:
            self._recorder_came.set()

    def set_counters_source(self, fn: Callable[[], dict[str, int]]) -> None:
        """Extra counters (e.g. a core's) merged into every status and the stats file."""
        self._extra_counters = fn

    def all_counters(self) -> dict[str, int]:
        out = {k: int(v) for k, v in self.counters.items()}
        out.update({f"auth_{k}": v for k, v in dict(self.auth.rejected).items()})
        if self._extra_counters is not None:
            out.update({k: int(v) for k, v in self._extra_counters().items()})
        return out

    def publish_status(self, state: str | None = None) -> None:
        if state is not None:
            self.state = state
        if self._status_pub is None:
            return
        counters = dict(sorted(self.all_counters().items())[:256])
        self._status_pub.put(
            ServiceStatus(
                run=self.config.run,
                service=self.name,
                pid=os.getpid(),
                state=self.state,
                t=time.time(),
                counters=counters,
                incarnation=self.incarnation,
            )
        )
        self._last_status = time.monotonic()

    def status_due_in(self) -> float:
        """Seconds until the periodic status is due (0 when it is)."""
        return max(0.0, self._last_status + self.config.status_period - time.monotonic())

    def tick(self) -> None:
        """Publish the periodic status when due, and at once for a recorder that has just come (it records the
        service's state from then on: a run killed before the next periodic status still shows who was running)."""
        if self._recorder_came.is_set():
            self._recorder_came.clear()
            self.publish_status()
        elif time.monotonic() - self._last_status >= self.config.status_period:
            self.publish_status()

    # -- end ---------------------------------------------------------------------------------------------------
    def write_stats(self, **extra: Any) -> None:
        path = getattr(self.config, "stats_out", None)
        if not path:
            return
        data = {
            "service": self.name,
            "incarnation": self.incarnation,
            "pid": os.getpid(),
            "cpu_s": round(time.process_time(), 3),
            "cpu_since_ready_s": round(time.process_time() - (self._cpu_at_ready or 0.0), 3),
            "counters": self.all_counters(),
            "gc": {"frozen": gc.get_freeze_count(), "collections": [g["collections"] for g in gc.get_stats()]},
            "samples": {k: list(v) for k, v in self.samples.items()},
            **extra,
        }
        atomic_write(path, json.dumps(data).encode())  # whole or not at all: a full disk leaves no 0-byte file


_CURRENT: list[ServiceRuntime | None] = [None]  # this process's runtime (its final state sets the exit code)


def load_auth(name: str, config: Any, incarnation: str, process_default: bool = True) -> Any:
    """This service's signer and checker from its credential file (common/wire/auth.py), installed as the process's
    default for every publisher and inbox (unless `process_default` is False: tests that build a runtime in
    their own process). Raises AuthError (one line) without one."""
    from common.wire.auth import Auth, AuthError, load_credential
    from common.wire.transport import set_default_auth

    path = getattr(config, "credentials", None)
    if not path:
        raise AuthError(
            f"{name}: no --credentials file; the launcher makes them, or `python -m services credentials "
            f"--run {config.run} --out DIR` for services started by hand (docs/security.md)"
        )
    cred = load_credential(path, run=config.run, identity=name)
    auth = Auth(
        cred, incarnation, max_past=getattr(config, "max_past", 600.0), max_future=getattr(config, "max_future", 10.0)
    )
    if process_default:
        set_default_auth(auth)
    return auth


def wait_alive(
    session: Any, run: str, names: tuple[str, ...] | list[str], timeout: float, stop: threading.Event | None = None
) -> set[str]:
    """Wait until every service in `names` holds its liveliness token; returns those still missing."""
    missing = set(names)
    if not missing:
        return missing
    cond = threading.Condition()
    alive: set[str] = set()

    def on_sample(sample: Any) -> None:
        import zenoh

        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with cond:
            if sample.kind == zenoh.SampleKind.PUT:
                alive.add(name)
            else:
                alive.discard(name)
            cond.notify_all()

    sub = session.liveliness().declare_subscriber(alive_key(run), on_sample, history=True)
    try:
        deadline = time.monotonic() + timeout
        with cond:
            while not missing <= alive:
                left = deadline - time.monotonic()
                if left <= 0 or (stop is not None and stop.is_set()):
                    break
                cond.wait(min(left, 0.1))
            return missing - alive
    finally:
        sub.undeclare()


def apply_torch_threads() -> None:
    """One torch thread and one BLAS thread: the same arithmetic live and in retrain (and room on small
    machines). numpy's OpenBLAS starts threads for products above about 10^5 multiply-adds (a minibatch of
    the one-hot Taxi's 519 inputs), which on a loaded 2-core machine thrash (docs/hyperparameters.md); the
    in-process runner limits them the same way. Torch is not imported for it (the numpy MLP never needs torch):
    if it is loaded already it is told now, else OMP_NUM_THREADS tells it when a torch network loads it."""
    from threadpoolctl import threadpool_limits

    os.environ["OMP_NUM_THREADS"] = "1"
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    threadpool_limits(1, user_api="blas")  # called, not entered: the limit holds for the process


def service_main(cls: type, main: Callable[[Any], int], argv: list[str] | None, prog: str, also: str = "") -> int:
    """Parse `cls` from the command line (or --config FILE) and run `main(config)`; `also` names the service's
    other commands in its --help."""
    from common.wire.auth import AuthError
    from common.config import parse_config

    doc = (cls.__doc__ or "").strip()
    config: Any = parse_config(cls, argv, prog=prog, description=f"{doc}\n\n{also}" if also else doc)
    try:
        code = main(config)
    except AuthError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except TerminalError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return TERMINAL_EXIT
    rt = _CURRENT[0]
    if code == 0 and rt is not None and rt.final_state == "failed":
        return 1  # ended without finishing its part: the launcher restarts it
    return code
