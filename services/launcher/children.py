"""The launcher's child processes: start one (its own process group, its log file), signal, stop, reap."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from common.config import config_record
from common.wire.transport import SERVICE_ZENOH_RUNTIME
from services.teacher.registry import ProcessSpec

ROOT = Path(__file__).resolve().parents[2]
KILL_AFTER = 3.0  # s between SIGTERM and SIGKILL
CHILD_UMASK = 0o077  # what a service writes in the run (logs, state, checkpoints) is its user's only: 0600 / 0700


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
    env.setdefault("ZENOH_RUNTIME", SERVICE_ZENOH_RUNTIME)  # (a service has one link: common/wire/transport.py)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")  # (see services/__main__.py)
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
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | (os.O_APPEND if restarts else os.O_TRUNC), 0o600)
    os.fchmod(fd, 0o600)  # (a log made before, by an older launcher, is made private too)
    log = os.fdopen(fd, "a" if restarts else "w")
    if restarts:
        log.write(f"\n----- restart {restarts} at {time.strftime('%H:%M:%S')} -----\n")
        log.flush()
    try:
        # In the launcher's own directory (the run's paths may be relative to it); the package is on PYTHONPATH.
        popen = subprocess.Popen(
            [sys.executable, "-m", *spec.module.split(), "--config", str(cfg_path)],
            env=child_env(),
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            umask=CHILD_UMASK,
        )
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
