"""Reading a run's log back: records in file order, from whole files, files cut short by a crash, files with
damaged chunks, and several segment files read as one log.

``read_log`` walks each file with :mod:`common.logs.mcap_scan`: a file that is not MCAP raises
:class:`NotMcapError` (one line: say it and exit non-zero); a damaged chunk is skipped and the reading goes on
with the next good one; a cut file is read up to its last complete chunk. What was lost is in
``reader.status`` (per file: chunks lost, messages lost by the index, bytes) and in a
:class:`LogRecoveryWarning`.

Topics are the keys without their run (``/step``); the reader puts the run back (from the file's ``hitl.run``
metadata, else its RunConfig), so every record carries its whole key (``hitl/<run>/step``).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import warnings
from pathlib import Path
from typing import Any
from collections.abc import Iterable, Iterator

from mcap.records import Channel, Message as McapMessage, Metadata, Schema

from common.logs.mcap_scan import NotMcapError, ScanResult, scan
from common.protocol import ProtocolError, RunConfig, decode, key_from_topic

METADATA_NAME = "hitl.run"
CHANNEL_METADATA = "hitl.channel"  # a channel's id and topic, repeated outside the chunks

__all__ = [
    "LogRecord",
    "FileStatus",
    "ReadStatus",
    "LogReader",
    "LogRecoveryWarning",
    "NotMcapError",
    "identity",
    "read_log",
    "load_log",
]


class LogRecoveryWarning(UserWarning):
    """A log file was incomplete or damaged; what could be read was read, the rest is reported lost."""


@dataclasses.dataclass(frozen=True)
class LogRecord:
    key: str
    log_time: int  # ns since the epoch
    data: bytes  # the payload as received
    message: Any  # the decoded message (None when decode=False or when it failed to decode)
    publish_time: int = 0
    segment: int = 0
    error: ProtocolError | None = None


@dataclasses.dataclass
class FileStatus:
    path: str
    size: int
    bytes_read: int = 0  # end of the last record read completely
    messages: int = 0
    chunks: int = 0  # chunks read whole
    data_complete: bool = False  # the DataEnd record was read: no message lost at the end
    complete: bool = False  # the footer was read: a properly finished file
    error: str | None = None  # what stopped the reading, for an incomplete file
    chunks_lost: int = 0  # damaged chunks (or damaged stretches) skipped
    messages_lost: int = 0  # messages in them, as their message index says (0 when the index is gone too)
    bytes_lost: int = 0
    lost: list[str] = dataclasses.field(default_factory=list)  # one line per damaged stretch
    unknown_channel: int = 0  # messages whose channel was defined in a lost chunk (skipped)


@dataclasses.dataclass
class ReadStatus:
    files: list[FileStatus] = dataclasses.field(default_factory=list)
    messages: int = 0
    undecodable: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    # read whole but not decoded here: their decoder is an extra not installed (by module, e.g. foxglove)
    needs_extra: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    duplicate_configs_skipped: int = 0
    duplicates_skipped: collections.Counter = dataclasses.field(default_factory=collections.Counter)  # by kind

    @property
    def complete(self) -> bool:
        return all(f.complete for f in self.files)

    @property
    def truncated(self) -> list[str]:
        """Files whose data section was cut short (messages after the last complete chunk are lost)."""
        return [f.path for f in self.files if not f.data_complete]

    @property
    def damaged(self) -> list[str]:
        """Files with damaged chunks that were skipped (the chunks after them were read)."""
        return [f.path for f in self.files if f.chunks_lost]

    def losses(self) -> list[str]:
        """One line per thing that could not be read (empty: every message of every file was read): data cut
        off at the end, damaged chunks skipped, messages on channels defined in a lost chunk, undecodable ones.
        A missing summary section (data complete, footer gone) loses nothing and is not listed."""
        out = []
        for f in self.files:
            if not f.data_complete:
                out.append(
                    f"{f.path}: truncated: {f.size - f.bytes_read} bytes after the last complete record "
                    f"(offset {f.bytes_read} of {f.size}) not read ({f.error})"
                )
            if f.chunks_lost:
                out.append(
                    f"{f.path}: skipped {f.chunks_lost} damaged chunk(s), {f.bytes_lost} bytes, "
                    f"{f.messages_lost} messages by their index ({'; '.join(f.lost[:3])}"
                    f"{'; ...' if len(f.lost) > 3 else ''})"
                )
            if f.unknown_channel:
                out.append(f"{f.path}: skipped {f.unknown_channel} messages on channels defined in a lost chunk")
        if self.undecodable:
            out.append(f"{sum(self.undecodable.values())} messages did not decode: {dict(self.undecodable)}")
        return out

    def summary(self) -> str:
        parts = [f"{self.messages} messages from {len(self.files)} file(s)"]
        for f in self.files:
            if not f.data_complete:
                parts.append(
                    f"{f.path}: truncated, recovered {f.messages} messages in {f.chunks} complete chunks "
                    f"({f.bytes_read} of {f.size} bytes; {f.error})"
                )
            elif not f.complete:
                parts.append(f"{f.path}: all data read, summary missing ({f.error})")
            if f.chunks_lost:
                parts.append(
                    f"{f.path}: skipped {f.chunks_lost} damaged chunk(s), {f.bytes_lost} bytes, "
                    f"{f.messages_lost} messages lost by their index ({'; '.join(f.lost[:3])})"
                )
            if f.unknown_channel:
                parts.append(f"{f.path}: {f.unknown_channel} messages on channels defined in a lost chunk")
        if self.undecodable:
            parts.append(f"undecodable: {dict(self.undecodable)}")
        if self.needs_extra:
            parts.append(f"not decoded (their module is not installed): {dict(self.needs_extra)}")
        if self.duplicates_skipped:
            parts.append(f"duplicates skipped: {dict(self.duplicates_skipped)}")
        return "; ".join(parts)


class LogReader:
    """Iterate to get :class:`LogRecord` in file order; ``status``, ``metadata`` and ``run_config`` fill in
    as files are read (complete after the iteration ends). Iterable once."""

    def __init__(self, paths: list[Path], *, decode_messages: bool = True, dedup: bool = True):
        self.paths = paths
        self.decode_messages = decode_messages
        self.dedup = dedup and decode_messages
        self._seen: set[tuple] = set()
        self.status = ReadStatus()
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.run_config: RunConfig | None = None
        self.schemas: dict[str, Schema] = {}  # by schema name
        self._used = False

    def __iter__(self) -> Iterator[LogRecord]:
        if self._used:
            raise RuntimeError("a LogReader can be iterated once; call read_log again")
        self._used = True
        for segment, path in enumerate(self.paths):
            yield from self._read_file(segment, path)

    def _read_file(self, segment: int, path: Path) -> Iterator[LogRecord]:
        fs = FileStatus(str(path), path.stat().st_size)
        self.status.files.append(fs)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        scanned = ScanResult()
        run: list[str | None] = [None]
        for r in scan(path, scanned):  # raises NotMcapError for a file that is not MCAP
            if isinstance(r, Schema):
                schemas[r.id] = r
                self.schemas[r.name] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
            elif isinstance(r, Metadata):
                if r.name == METADATA_NAME and r.metadata.get("run"):
                    run[0] = r.metadata["run"]
                elif r.name == CHANNEL_METADATA and r.metadata.get("id", "").isdigit():
                    cid = int(r.metadata["id"])
                    channels.setdefault(
                        cid,
                        Channel(
                            id=cid,
                            schema_id=0,
                            topic=r.metadata.get("topic", ""),
                            message_encoding=r.metadata.get("message_encoding", ""),
                            metadata={},
                        ),
                    )
                    continue  # not one of the metadata records readers look at
                self.metadata.append((r.name, dict(r.metadata)))
            elif isinstance(r, McapMessage):
                if r.channel_id not in channels:
                    fs.unknown_channel += 1
                    continue
                out = self._record(segment, r, channels, run)
                if out is not None:
                    fs.messages += 1
                    self.status.messages += 1
                    yield out
        fs.bytes_read, fs.chunks, fs.error = scanned.bytes_read, scanned.chunks, scanned.error
        fs.data_complete, fs.complete = scanned.data_complete, scanned.complete
        fs.chunks_lost, fs.messages_lost = len(scanned.lost), scanned.messages_lost
        fs.bytes_lost = sum(c.length for c in scanned.lost)
        fs.lost = [
            f"offset {c.offset}, {c.length} bytes, {'?' if c.messages is None else c.messages} messages: {c.reason}"
            for c in scanned.lost
        ]
        if not fs.data_complete:
            warnings.warn(
                f"{path}: incomplete log, recovered {fs.messages} messages in {fs.chunks} complete "
                f"chunks ({fs.bytes_read} of {fs.size} bytes); the rest is lost ({fs.error})",
                LogRecoveryWarning,
                stacklevel=3,
            )
        if fs.chunks_lost:
            warnings.warn(
                f"{path}: skipped {fs.chunks_lost} damaged chunk(s) ({fs.bytes_lost} bytes, "
                f"{fs.messages_lost} messages by their index) and read on: {'; '.join(fs.lost[:3])}",
                LogRecoveryWarning,
                stacklevel=3,
            )

    def _record(
        self, segment: int, m: McapMessage, channels: dict[int, Channel], run: list[str | None]
    ) -> LogRecord | None:
        topic = channels[m.channel_id].topic
        if run[0] is None and topic == "/config":  # no metadata: the run config names the run
            try:
                run[0] = RunConfig.decode(m.data).run
            except ProtocolError:
                pass
        try:
            key = key_from_topic(topic, run[0] or "unknown-run")
        except ProtocolError:
            key = topic
        message, error = None, None
        if self.decode_messages:
            try:
                message = decode(key, m.data)
            except ProtocolError as e:
                error = e
                self.status.undecodable[e.reason] += 1
            except ImportError as e:  # a part whose decoder is an extra (the scene: foxglove-sdk) is not installed
                self.status.needs_extra[e.name] += 1
        if self.decode_messages and isinstance(message, RunConfig):
            if self.run_config is None:
                self.run_config = message
            elif (message.run, message.config) == (self.run_config.run, self.run_config.config):
                self.status.duplicate_configs_skipped += 1
                return None  # the same run config repeated at the top of a later segment
            else:
                warnings.warn(f"segment {segment} has a different run config", LogRecoveryWarning, stacklevel=4)
        if self.dedup and message is not None:
            ident = identity(message)
            if ident is not None:
                if ident in self._seen:
                    self.status.duplicates_skipped[ident[0]] += 1
                    return None
                self._seen.add(ident)
        return LogRecord(key, m.log_time, bytes(m.data), message, m.publish_time, segment, error)


def identity(message: Any) -> tuple | None:
    """What makes a message unique within a run, for messages that may be published twice (re-sent to a
    restarted recorder or learner; docs/faults.md); None for the others (statuses, frames, ...)."""
    from common.protocol import Credit, EpisodeSummary, Feedback, Ingest, Log, Step, Weights, WeightsSnapshot

    if isinstance(message, Step):
        return ("step", message.incarnation, message.seq)
    if isinstance(message, Feedback):
        return ("feedback", message.teacher_id, message.seq)
    if isinstance(message, Ingest):
        return ("ingest", message.learner, message.seq)
    if isinstance(message, EpisodeSummary):
        return ("episode", message.incarnation, message.episode)
    if isinstance(message, Weights):
        return ("weights", message.incarnation, message.version)
    if isinstance(message, Credit):
        return ("credit", message.teacher_id, message.seq)
    if isinstance(message, WeightsSnapshot):
        return ("snapshot", message.incarnation, message.version, message.reason)
    if isinstance(message, Log):
        return ("log", message.name, message.timestamp.sec, message.timestamp.nsec, message.message)
    return None


def read_log(
    path: str | os.PathLike | Iterable[str | os.PathLike],
    *,
    decode: bool = True,
    segments: bool = True,
    dedup: bool = True,
) -> LogReader:
    """Records of a log in file order.

    ``path``: a file (with ``segments=True``, also its later segments ``<stem>.1<suffix>``, ... as one log),
    a directory (its ``session.mcap`` segments), or a list of files read in the given order.
    ``decode``: decode each payload by its key (failures are counted in ``status.undecodable`` and the record
    is still yielded with ``error`` set). Later segments' copies of the same run config are skipped.
    ``dedup`` (with ``decode``): a message published twice (the same :func:`identity`: re-sent to a restarted
    recorder) is yielded once, the first time; ``status.duplicates_skipped`` counts the others by kind.
    """
    from common.logs.mcap_log import segment_paths

    if isinstance(path, (str, os.PathLike)):
        p = Path(path)
        if p.is_dir():
            p = p / "session.mcap"
        paths = segment_paths(p) if segments else [p]
        if not paths:
            raise FileNotFoundError(p)
    else:
        paths = [Path(x) for x in path]
    return LogReader(paths, decode_messages=decode, dedup=dedup)


def load_log(path: Any, **kwargs: Any) -> tuple[list[LogRecord], ReadStatus]:
    """All records and the read status at once."""
    reader = read_log(path, **kwargs)
    records = list(reader)
    return records, reader.status
