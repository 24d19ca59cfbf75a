"""The run directory: a unique name, an exclusive lock, the run's credentials, and what a full or read-only
disk does (a one-line error, a clean stop, a summary.json that says why)."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import secrets
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

SUBDIRS = ("config", "logs", "stats", "state")
PRIVATE_DIR = 0o700  # the run's folders: its logs and state hold what opens the run (the console's key, secrets)
SUMMARY_RESERVE = 64 * 1024  # bytes summary.json holds from the start, so a full disk can still say why
LOCK_FILE = ".lock"
RUNNING = json.dumps({"outcome": "running"})  # summary.json until the launcher writes the real one


class RunDirError(Exception):
    """The run cannot use its directory (in use, exists, unwritable, disk full): one line for the user."""


def recorded_router(rundir: Path, stopped: Callable[[], bool], timeout: float | None = None) -> str | None:
    """The router endpoint in the run's record (`config/run.json`), waiting until the launcher has written it:
    after its router listens and before any service starts, whole (`os.replace`). None if `stopped()` first; a
    TimeoutError after `timeout` s. For a tool started before the run (a flood, the bench's pinger)."""
    record = rundir / "config" / "run.json"
    deadline = None if timeout is None else time.monotonic() + timeout
    while not stopped():
        try:
            return str(json.loads(record.read_text())["launcher"]["endpoint"])
        except FileNotFoundError:
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"no run record at {record} after {timeout:g} s") from None
            time.sleep(0.05)
    return None


def default_run_name() -> str:
    """`live-<date>-<time>-<random>`: two launchers started in the same second never share a run."""
    return f"live-{time.strftime('%Y%m%d-%H%M%S')}-{secrets.token_hex(3)}"


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def describe(exc: OSError) -> str:
    return f"{exc.strerror or exc}{' (' + str(exc.filename) + ')' if exc.filename else ''}"


class RunDir:
    """Creates and locks `out/run`. The lock (an flock on `.lock`, held until the launcher exits, released by
    the kernel even on SIGKILL) keeps a second launcher out of a run directory in use."""

    def __init__(self, out: str | os.PathLike, run: str):
        self.path = Path(out) / run
        self._lock_fd: int | None = None

    def lock(self) -> int:
        """Take the run's lock (RunDirError if a launcher holds it); returns its fd."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError as exc:
            raise RunDirError(f"cannot write the run directory {self.path}: {describe(exc)}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RunDirError(f"{self.path} is in use by another launcher; choose another --run") from None
        self._lock_fd = fd
        return fd

    def open(self) -> None:
        fd = self.lock()
        if (self.path / "session.mcap").exists():
            raise RunDirError(f"{self.path}/session.mcap exists; choose another --run")
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            os.chmod(self.path, PRIVATE_DIR)  # no other local user reads the run's logs, state or credentials
            for sub in SUBDIRS:
                (self.path / sub).mkdir(mode=PRIVATE_DIR, exist_ok=True)
                os.chmod(self.path / sub, PRIVATE_DIR)
            self.reserve_summary()
        except OSError as exc:
            raise RunDirError(f"cannot write the run directory {self.path}: {describe(exc)}") from None

    def close(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    # -- credentials -----------------------------------------------------------------------------------------
    def make_credentials(self, run: str, identities: list[str]) -> dict[str, Path]:
        """A new run secret and one credential per identity under `credentials/` (0700, files 0600). Everything the
        launcher starts runs as this user on this machine: a service credential each (teachers that join from
        elsewhere get a teacher credential: `python -m services credentials --teacher ID`)."""
        from common.wire.auth import make_run_credentials

        return make_run_credentials(self.path / "credentials", run, services=identities)

    # -- disk ------------------------------------------------------------------------------------------------
    def free_mb(self) -> float:
        try:
            return shutil.disk_usage(self.path).free / (1 << 20)
        except OSError:
            return float("inf")

    def reserve_summary(self) -> None:
        """Write summary.json now, padded: its blocks are ours, so the final summary fits even on a full disk."""
        (self.path / "summary.json").write_text(RUNNING + " " * (SUMMARY_RESERVE - len(RUNNING)))

    def write_summary(self, summary: dict[str, Any]) -> None:
        """The final summary.json: whole if the disk allows, else the essentials in the reserved space."""
        path = self.path / "summary.json"
        text = json.dumps(summary, indent=2)
        tmp = path.with_name(".summary.json.tmp")
        try:
            tmp.write_text(text)
            os.replace(tmp, path)
            return
        except OSError:
            tmp.unlink(missing_ok=True)
        text = fit_reserve(summary)
        with open(path, "r+") as f:  # overwrite in place: no new blocks needed
            f.write(text)
            f.truncate()


# What a summary that must fit the reserve leaves out first: lists that grow with the run (every count stays).
BULKY = (
    "episodes",
    "exit_history",
    "services",
    "learners",
    "unfinished_episodes",
    "returns",
    "restarts",
    "learner_chain",
    "face",
)


def fit_reserve(summary: dict[str, Any]) -> str:
    """The summary as compact JSON within SUMMARY_RESERVE bytes: the bulky lists go first (named under
    `left_out`), every count and the outcome stay; only a summary still too big is cut to its essentials."""
    out = dict(summary)
    left_out = []
    for key in BULKY:
        text = json.dumps(out, separators=(",", ":"))
        if len(text.encode()) <= SUMMARY_RESERVE:
            return text
        if key in out:
            del out[key]
            left_out.append(key)
            out["left_out"] = left_out + ["(disk full: only what fits the space reserved for summary.json)"]
    text = json.dumps(out, separators=(",", ":"))
    if len(text.encode()) <= SUMMARY_RESERVE:
        return text
    keep = {k: summary[k] for k in ("run", "outcome", "error", "wall_s") if k in summary}
    return json.dumps(keep)[:SUMMARY_RESERVE]
