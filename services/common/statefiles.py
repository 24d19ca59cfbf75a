"""State files written whole or not at all: readers see the old or the new file, also after a SIGKILL."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def atomic_write(path: str | os.PathLike, data: bytes) -> None:
    """Write to a temporary file beside `path`, then `os.replace`: readers see the old or the new file whole,
    also after a SIGKILL in the middle (the temporary file is left behind and overwritten next time); a failed
    write (a full disk) removes its temporary file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
        os.replace(tmp, path)
    except BaseException:  # a full disk: no partial temporary file left behind
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    atomic_write(path, json.dumps(obj, sort_keys=True).encode())


def read_json(path: str | os.PathLike) -> Any | None:
    """The JSON object in `path`, or None if there is none (a damaged file raises: never silently reset)."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return None


def port_to_bind(port: int, port_file: str | None) -> int:
    """`port`; for 0, the port an earlier start of this server wrote to `port_file` (a restart keeps the address
    the launcher printed), else 0 (the system's choice at the bind)."""
    if port == 0 and port_file is not None:
        try:
            return int(Path(port_file).read_text())
        except (OSError, ValueError):
            return 0
    return port
