"""A run whose launcher died before writing its summary (SIGKILL, a power cut): summary.json still says
`{"outcome": "running"}`. `finish_from_log` writes the summary from the run's log, as the launcher would have,
with the outcome `interrupted` and a note saying so; `python -m services.replay summary RUN_DIR --write` and
the next `services up` with the same `--out` call it."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from services.launcher.report import write_summary_from_log
from services.launcher.rundir import RUNNING, RunDir, RunDirError

KILLED_NOTE = (
    "the launcher ended without writing this summary (killed?); the counts were recomputed from the log "
    "by {by}; exit codes, restarts and wall time are unknown"
)


def summary_state(path: Path) -> str | None:
    """The outcome summary.json states (`running` while the launcher runs, or killed), or None without one."""
    try:
        return str(json.loads((path / "summary.json").read_text()).get("outcome"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, AttributeError):
        return "unreadable"


def left_running(path: Path) -> bool:
    """summary.json is still the launcher's first one (read without parsing a large final summary)."""
    try:
        with open(path / "summary.json", "rb") as f:
            return f.read(len(RUNNING)) == RUNNING.encode()
    except OSError:
        return False


def services_running(path: Path) -> list[int]:
    """Pids of this run's services still alive (their argv names the run directory): a killed launcher's
    children notice and exit within seconds; until then the log is still being written."""
    import psutil

    names = {str(path), str(path.resolve())}
    mine = {os.getpid(), *(p.pid for p in psutil.Process().parents())}
    found = []
    for p in psutil.process_iter(["pid", "cmdline", "status"]):
        try:
            argv = p.info["cmdline"] or []
            if p.pid in mine or p.info["status"] == psutil.STATUS_ZOMBIE or "-m" not in argv:
                continue
            module = argv[argv.index("-m") + 1] if argv.index("-m") + 1 < len(argv) else ""
            if (
                module.startswith("services.")
                and module != "services.replay"
                and any(n in a for a in argv for n in names)
            ):
                found.append(p.pid)
        except (psutil.Error, ValueError):
            continue
    return found


def finish_from_log(path: str | os.PathLike, by: str) -> tuple[dict[str, Any] | None, str]:
    """Write the summary of a run whose launcher died. Returns (the summary written or None, one line for the
    user); RunDirError when it cannot be done now (a launcher or its services still run it)."""
    path = Path(path)
    state = summary_state(path)
    if state is None:
        return None, f"{path}: no summary.json (not a run of `services up`): nothing written"
    if state not in ("running", "unreadable"):
        return None, f"{path}/summary.json is final already (outcome {state}): left as it is"
    rundir = RunDir(path.parent, path.name)
    rundir.lock()  # RunDirError while its launcher runs
    try:
        alive = services_running(path)
        if alive:
            raise RunDirError(f"{path}: services of this run still run (pids {alive}); try again when they exit")
        summary: dict[str, Any] = {
            "run": path.name,
            "outcome": "interrupted",
            "error": KILLED_NOTE.format(by=by),
            "finished_from_log": True,
        }
        record = launcher_record(path)
        if record.get("run"):
            summary["run"] = record["run"]
        if record.get("endpoint"):
            summary["endpoint"] = record["endpoint"]
        title = (
            f"{record.get('algo', '?')} on {record.get('env', '?')} (live, teacher {record.get('teacher', '?')}, "
            f"seed {record.get('seed', '?')}; launcher killed)"
        )
        write_summary_from_log(summary, rundir, title)
    finally:
        rundir.close()
    return summary, f"wrote {path}/summary.json from the log (outcome interrupted: its launcher was killed)"


def launcher_record(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads((path / "config" / "run.json").read_text()).get("launcher") or {})
    except (OSError, ValueError, AttributeError):
        return {}


def finish_unfinished_runs(out: str | os.PathLike) -> None:
    """Before a new run in `out`: finish every run there whose launcher died (one line each; a run that is
    still going or cannot be finished now is left alone)."""
    out = Path(out)
    if not out.is_dir():
        return
    for path in sorted(p for p in out.iterdir() if p.is_dir() and left_running(p)):
        try:
            written, line = finish_from_log(path, by="the next `services up` in its --out")
        except (RunDirError, OSError):
            continue
        if written is not None:
            print(line, file=sys.stderr, flush=True)
