"""Helpers of the live tests: run the launcher as a process, find processes a run left behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[2]


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT)
    return e


@dataclass
class Launch:
    popen: subprocess.Popen
    rundir: Path
    t_start: float
    out: str = ""
    t_exit: float | None = None

    def wait(self, timeout: float) -> int:
        try:
            self.out, _ = self.popen.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            kill_tree(self.popen.pid)
            self.out, _ = self.popen.communicate()
            raise
        self.t_exit = time.time()
        return self.popen.returncode

    def summary(self) -> dict:
        return json.loads((self.rundir / "summary.json").read_text())


def start_up(tmp_path: Path, run: str, *args: str) -> Launch:
    """`python -m services up` in its own session (so a test can send it SIGINT like a terminal would)."""
    # no learning_curve.png unless a test asks for it (`--curve true`): matplotlib costs each run about 1 s of CPU
    curve = [] if "--curve" in args else ["--curve", "false"]
    cmd = [sys.executable, "-m", "services", "up", "--out", str(tmp_path), "--run", run, "--progress", "false"]
    cmd += [*curve, *args]
    popen = subprocess.Popen(
        cmd, cwd=ROOT, env=env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )
    return Launch(popen, tmp_path / run, time.time())


def processes_mentioning(text: str) -> list[psutil.Process]:
    """Live processes whose command line mentions `text` (a run directory is in every service's argv)."""
    found = []
    for p in psutil.process_iter(["pid", "cmdline", "status"]):
        try:
            if p.info["status"] == psutil.STATUS_ZOMBIE:
                continue
            if any(text in part for part in (p.info["cmdline"] or [])):
                found.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
    return found


def kill_tree(pid: int) -> None:
    try:
        parent = psutil.Process(pid)
        procs = parent.children(recursive=True) + [parent]
    except psutil.NoSuchProcess:
        return
    for p in procs:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass


def assert_nothing_left(rundir: Path, timeout: float = 3.0) -> None:
    deadline = time.time() + timeout
    left = processes_mentioning(str(rundir))
    while left and time.time() < deadline:
        time.sleep(0.1)
        left = processes_mentioning(str(rundir))
    for p in left:
        kill_tree(p.pid)
    assert not left, f"processes left behind: {[(p.pid, p.info['cmdline']) for p in left]}"


def wait_for(predicate, timeout: float, period: float = 0.1) -> bool:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return False


_CREDENTIALS: dict[str, str] = {}
_CREDENTIALS_DIR: tempfile.TemporaryDirectory | None = None


def actor_credentials(run: str) -> str:
    """The actor's credential file of a throwaway run, made once per test process in a directory removed when the
    process exits (for tests that cannot take `tmp_path`: Hypothesis runs one function many times)."""
    global _CREDENTIALS_DIR
    from common.wire.auth import make_run_credentials

    if run not in _CREDENTIALS:
        if _CREDENTIALS_DIR is None:
            _CREDENTIALS_DIR = tempfile.TemporaryDirectory(prefix="creds-")
        _CREDENTIALS[run] = str(make_run_credentials(os.path.join(_CREDENTIALS_DIR.name, run), run)["actor"])
    return _CREDENTIALS[run]
