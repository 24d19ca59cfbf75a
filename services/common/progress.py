"""A service's progress file (the actor's episodes done, a teacher's next feedback seq): a small JSON object
rewritten before each thing it counts, so that a restarted service continues where the killed one stopped.

It is rewritten in place: the first write replaces the file atomically (`statefiles.atomic_write`) with the record
padded by spaces to a fixed width (JSON allows trailing whitespace), and later writes overwrite that width at
offset 0 of the file kept open, with one `pwrite`. A single write of a few dozen bytes to a regular file is not
split by a kill, so a reader after a SIGKILL sees the old or the new record whole, as with the atomic rename,
at about 1/100 of its cost (one system call instead of six, no directory update: measured 1.5 us against
220 us on an idle ext4, and the rename's cost grows with the machine's load). A record longer than the width
goes through the atomic rename again, with a wider width.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from services.common.statefiles import atomic_write, read_json

MIN_WIDTH = 64  # bytes of the padded record


class ProgressFile:
    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fd: int | None = None
        self._width = 0

    def read(self) -> Any | None:
        """The record an earlier incarnation left (None if there is none)."""
        return read_json(self.path)

    def write(self, record: Any) -> None:
        data = json.dumps(record, sort_keys=True).encode()
        if self._fd is not None and len(data) <= self._width:
            os.pwrite(self._fd, data.ljust(self._width), 0)
            return
        self.close()
        self._width = max(MIN_WIDTH, 2 * len(data))
        atomic_write(self.path, data.ljust(self._width))
        self._fd = os.open(self.path, os.O_WRONLY)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
