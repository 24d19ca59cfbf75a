"""Which project files one call runs through, measured in the running services (docs/architecture.md).

A service marks the calls that make up a step's or a press's path with `@traced("label")`. When the environment
variable `HITL_TRACE` names a folder, each marked call is profiled on its own thread (`sys.setprofile`, for that
call only) and one JSON line per distinct call (its functions differ from every earlier call's) is appended to
`HITL_TRACE/trace-<pid>.jsonl`: the label and every project function that ran inside it, as `file:qualified
name`. Only the project's own code counts (`common/`, `services/`, `experiments/`): not third-party packages, not
tests, not a module's import-time code.

Without `HITL_TRACE` the decorator returns the function itself, so the services pay nothing.
`tests/test_paths_traced.py` reads the lines and writes the paths into the doc.
"""

from __future__ import annotations

import functools
import json
import os
import sys
import threading
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar, cast

ENV = "HITL_TRACE"
ROOT = Path(__file__).resolve().parents[1]
PROJECT_DIRS = ("common/", "services/", "experiments/")
SELF = "common/pathtrace.py"  # the marks' own wrapper is not part of any path
MAX_CALLS = 300  # distinct calls per label and process: a short run's, never a file that grows without bound

F = TypeVar("F", bound=Callable[..., Any])


def project_file(filename: str) -> str | None:
    """`filename` relative to the checkout if it is one of the project's own source files, else None."""
    try:
        rel = Path(filename).resolve().relative_to(ROOT).as_posix()
    except ValueError:  # outside the checkout: the standard library, the venv's packages
        return None
    return rel if rel.startswith(PROJECT_DIRS) and rel != SELF else None


class CallRecorder:
    """The project functions called on this thread while it is installed (a `sys.setprofile` function)."""

    def __init__(self) -> None:
        self.functions: set[str] = set()
        self._files: dict[str, str | None] = {}  # filename -> project path (None: not ours), looked up once

    def __call__(self, frame: FrameType, event: str, arg: object) -> None:
        if event != "call":
            return
        code = frame.f_code
        if code.co_name == "<module>":  # an import running a module's body is not part of the path
            return
        filename = code.co_filename
        if filename not in self._files:
            self._files[filename] = project_file(filename)
        rel = self._files[filename]
        if rel is not None:
            self.functions.add(f"{rel}:{code.co_qualname}")


class TraceLog:
    """One process's trace file: each label's distinct calls (a call that ran the same functions as one already
    written is only counted: a service idling for a minute would otherwise fill the cap before its first step)."""

    def __init__(self, folder: str) -> None:
        self.path = Path(folder) / f"trace-{os.getpid()}.jsonl"
        self.calls: Counter[str] = Counter()  # calls made, written or not
        self.written: dict[str, set[frozenset[str]]] = {}
        self.lock = threading.Lock()

    def wants(self, label: str) -> bool:
        return len(self.written.get(label, ())) < MAX_CALLS

    def write(self, label: str, functions: set[str]) -> None:
        with self.lock:
            call, seen = self.calls[label], self.written.setdefault(label, set())
            self.calls[label] += 1
            if frozenset(functions) in seen:
                return
            seen.add(frozenset(functions))
            line = json.dumps({"label": label, "call": call, "functions": sorted(functions)})
            with self.path.open("a") as f:
                f.write(line + "\n")


_log: TraceLog | None = None


def _trace_log() -> TraceLog | None:
    global _log
    folder = os.environ.get(ENV)
    if folder and _log is None:
        _log = TraceLog(folder)
    return _log


def traced(label: str) -> Callable[[F], F]:
    """Mark a call as one piece of a path; profiled only when `HITL_TRACE` is set."""

    def mark(fn: F) -> F:
        log = _trace_log()
        if log is None:
            return fn

        @functools.wraps(fn)
        def profiled(*args: Any, **kwargs: Any) -> Any:
            if not log.wants(label) or sys.getprofile() is not None:  # (nested marks: the outer one records)
                return fn(*args, **kwargs)
            recorder = CallRecorder()
            sys.setprofile(recorder)
            try:
                return fn(*args, **kwargs)
            finally:
                sys.setprofile(None)
                log.write(label, recorder.functions)

        return cast(F, profiled)

    return mark


def read_traces(folder: Path) -> list[dict[str, Any]]:
    """Every traced call written under `folder`, from all processes."""
    calls = []
    for path in sorted(folder.glob("trace-*.jsonl")):
        calls += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return calls


def files_of(functions: list[str] | set[str]) -> set[str]:
    return {f.split(":", 1)[0] for f in functions}
