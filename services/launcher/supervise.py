"""Supervision: restarts of dead services (with their records), hung services (liveliness and progress
watched), and the launcher's foxglove.Log records."""

from __future__ import annotations

import collections
import contextlib
import signal
import sys
import threading
import time
from typing import Any

from services.launcher.children import Child, tail
from services.launcher.config import UpConfig

TOKEN_GRACE = 5.0  # s a service may run on after dropping its token (a clean exit takes well under a second)
# A token can also lapse on a machine so loaded that keep-alives come late; a process that still uses CPU is
# then not hung, unless it stays without its token for the status timeout (its session never came back).
MIN_STATUSES = 3  # statuses seen from an incarnation before its silence counts (it ticks in its main loop)
# How often the children's CPU times are read: reading one costs about 0.2-0.6 ms (psutil, /proc), which at
# every 50 ms pass of the launcher took some 5 % of a core from the run; once a second is fine against TOKEN_GRACE.
CPU_SAMPLE_PERIOD = 1.0
# The launcher's loop: a pass every BUSY_PASS s while something is under way (start-up, a restart, the end), every
# IDLE_PASS s in steady state. A liveliness change (a service ready, or gone with its session) and a signal wake
# it at once; 20 passes a second while nothing happens were most of what the launcher did in a paced run.
BUSY_PASS = 0.05
IDLE_PASS = 0.5


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of a process, None if it cannot be read (gone, or not ours)."""
    import psutil

    try:
        t = psutil.Process(pid).cpu_times()
    except (psutil.Error, OSError):
        return None
    return float(t.user + t.system)


class HangWatch:
    """Per service: whether it holds its liveliness token, and when its last status came. A process that runs
    on without its token (its Zenoh session lapsed: the process is stopped or stuck) or, once it has ticked a
    few times, without any status for `timeout` s, is hung."""

    def __init__(self, timeout: float):
        self.timeout = timeout
        self.held: set[str] = set()  # services holding their token (since their current process started)
        self.lost: dict[str, float] = {}  # service -> monotonic time its token went
        self.last_status: dict[str, float] = {}
        self.statuses: collections.Counter[str] = collections.Counter()
        self.ended: set[str] = set()  # said its last word ('stopped' / 'failed'): on its way out, not hung
        self.cpu: dict[str, tuple[float, float]] = {}  # service -> (CPU seconds, monotonic time they last grew)

    def progress(self, name: str, cpu_seconds: float | None) -> None:
        """The process's CPU time now (None if unknown): it grows while the process runs at all."""
        if cpu_seconds is None:
            return
        old = self.cpu.get(name)
        if old is None or cpu_seconds > old[0]:
            self.cpu[name] = (cpu_seconds, time.monotonic())

    def _idle_for(self, name: str, now: float) -> float:
        """Seconds since the process last used CPU (infinite when never measured)."""
        return now - self.cpu[name][1] if name in self.cpu else float("inf")

    def token(self, name: str, present: bool) -> None:
        if present:
            self.held.add(name)
            self.lost.pop(name, None)
        elif name in self.held:
            self.held.discard(name)
            self.lost[name] = time.monotonic()

    def status(self, name: str, state: str) -> None:
        self.last_status[name] = time.monotonic()
        self.statuses[name] += 1
        if state in ("stopped", "failed"):
            self.ended.add(name)

    def forget(self, name: str) -> None:
        """A new process of `name`: nothing known about it yet."""
        self.held.discard(name)
        self.ended.discard(name)
        self.lost.pop(name, None)
        self.last_status.pop(name, None)
        self.statuses.pop(name, None)
        self.cpu.pop(name, None)

    def why(self, name: str) -> str | None:
        now = time.monotonic()
        if name in self.ended:
            return None
        gone = now - self.lost[name] if name in self.lost else -1.0
        if gone > TOKEN_GRACE and (self._idle_for(name, now) > TOKEN_GRACE or gone > self.timeout):
            return f"its liveliness token is gone since {gone:.0f} s (Zenoh session lapsed) and it " + (
                f"used no CPU for {self._idle_for(name, now):.0f} s" if gone <= self.timeout else "never got it back"
            )
        if self.statuses[name] >= MIN_STATUSES and now - self.last_status[name] > self.timeout:
            return f"no status for {now - self.last_status[name]:.0f} s"
        return None


class Supervisor:
    """Restarts, their records, and the launcher's foxglove.Log records (on `hitl/<run>/log/launcher`, re-sent
    when the recorder comes back). Liveliness tokens tell when a restarted service is ready again."""

    def __init__(self, cfg: UpConfig, run: str, session: Any):
        from common.protocol import log_key
        from common.wire.transport import MessagePublisher
        from common.protocol import alive_key
        from common.wire.delivery import ResendRing
        from services.common.watches import AliveWatch

        self.cfg, self.run = cfg, run
        self.records: list[dict[str, Any]] = []
        self.restarts: dict[str, int] = collections.Counter()
        self.pending: dict[str, float] = {}  # service -> monotonic time of its restart
        self._alive: dict[str, list[float]] = collections.defaultdict(list)  # service -> wall times of PUTs
        self._lock = threading.Lock()
        self.ring = ResendRing(window=3600.0, max_items=1000)
        self.hangs = HangWatch(cfg.hang_timeout)
        self._next_cpu_sample = 0.0  # monotonic time of the next reading of the children's CPU times
        self.wake = threading.Event()  # the loop's next pass is due now (see rest())
        self.pub = MessagePublisher(session, log_key(run, "launcher"))
        self.recorder_watch = AliveWatch(session, run, ["recorder"])
        self._sub = session.liveliness().declare_subscriber(alive_key(run), self._on_alive, history=True)

    def _on_alive(self, sample: Any) -> None:
        import zenoh

        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive[name].append(time.time())
                self.hangs.token(name, True)
            else:
                self.hangs.token(name, False)
        self.wake.set()

    def rest(self, busy: bool) -> None:
        """Wait for the loop's next pass: BUSY_PASS s while `busy` or a restart is pending, else IDLE_PASS s,
        sooner when a liveliness change or a signal wakes it."""
        self.wake.wait(BUSY_PASS if busy or self.pending else IDLE_PASS)
        self.wake.clear()

    def say(self, text: str, level: int = 3) -> None:
        from common.protocol import Log, Time
        from common.wire.delivery import publish_kept

        print(f"\n[launcher] {text}", file=sys.stderr, flush=True)
        try:
            publish_kept(
                self.pub,
                Log(
                    timestamp=Time.from_seconds(time.time()),
                    level=level,
                    message=text[:8000],
                    name="launcher",
                    file="",
                    line=0,
                ),
                self.ring,
            )
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
        delay = min(8.0, self.cfg.restart_backoff * 2**k)
        self.restarts[name] += 1
        self.pending[name] = time.monotonic() + delay
        by_signal = rc < 0 and -rc in signal.Signals._value2member_map_
        how = f"signal {signal.Signals(-rc).name}" if by_signal else f"code {rc}"
        self.records.append(
            {
                "service": name,
                "restart": k + 1,
                "exit": rc,
                "how": how,
                "t_died": time.time(),
                "t_respawned": None,
                "t_ready": None,
                "recovered_s": None,
                "pid": child.popen.pid,
            }
        )
        self.say(
            f"{name} died ({how}); restarting in {delay:.1f} s (restart {k + 1} of {self.cfg.restart_limit}); "
            f"last lines of {child.log_path}:\n{tail(child.log_path, 5)}",
            4,
        )

    def hung(self, children: list[Child], statuses: Any) -> list[tuple[Child, str]]:
        """Services whose process runs but which have lost their liveliness token or stopped sending statuses."""
        while (got := statuses.get_message(timeout=0)) is not None:
            with self._lock:
                self.hangs.status(got[1].service, got[1].state)
        sample = time.monotonic() >= self._next_cpu_sample
        if sample:
            self._next_cpu_sample = time.monotonic() + CPU_SAMPLE_PERIOD
        with self._lock:
            for c in children if sample else ():
                self.hangs.progress(c.name, cpu_seconds(c.popen.pid))
            return [(c, why) for c in children if c.poll() is None and (why := self.hangs.why(c.name))]

    def kill_hung(self, child: Child, why: str) -> None:
        self.say(f"{child.name} (pid {child.popen.pid}) is hung: {why}; killing it", 4)
        with self._lock:
            self.hangs.forget(child.name)
        child.signal_group(signal.SIGKILL)

    def respawned(self, child: Child) -> None:
        with self._lock:
            self.hangs.forget(child.name)
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
