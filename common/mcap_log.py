"""MCAP logs of a run: one writer that a recorder (or any service) feeds with (key, bytes), and a reader
that gives the records back in file order, also from files cut short by a crash and from several
segment files (``session.mcap``, ``session.1.mcap``, ...).

Layout of every segment file:

- MCAP metadata ``hitl.run``: ``run``, ``protocol``, ``segment``, ``run_config`` (the RunConfig message as
  JSON);
- the first message: the RunConfig on ``hitl/<run>/config``;
- then one channel per key expression (topic = the key), one schema per message type (name = the type's
  ``TYPE_NAME``, encoding ``jsonschema``, data = its JSON Schema; Weights: the schema of its safetensors
  header, message encoding ``safetensors``), messages in arrival order, zstd chunks.

The writer finishes its chunk and flushes the file at least every ``flush_interval`` (1 s) while data
is pending (a background thread does it when no new message arrives), so a SIGKILL loses at most about
that much. A crashed file has no summary; ``read_log`` reads it sequentially up to its last complete
chunk, warns with counts (``LogRecoveryWarning``) and reports in ``reader.status``.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import os
import re
import threading
import time
import warnings
from pathlib import Path
from typing import Any, Iterable, Iterator

from mcap.records import Channel, Chunk, DataEnd, Footer, Message as McapMessage, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from common.protocol import PROTOCOL_VERSION, ProtocolError, RunConfig, config_key, decode, parse_key

METADATA_NAME = "hitl.run"
PROFILE = "hitl"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


class LogRecoveryWarning(UserWarning):
    """A log file was incomplete (crash or still being written); only its complete chunks were read."""


# -- segment files -----------------------------------------------------------------------------------------------

def segment_path(base: str | os.PathLike, index: int) -> Path:
    """``session.mcap`` -> index 0: ``session.mcap``, 1: ``session.1.mcap``, 2: ``session.2.mcap`` ..."""
    base = Path(base)
    if index == 0:
        return base
    return base.with_name(f"{base.stem}.{index}{base.suffix}")


def _segment_index(base: Path, path: Path) -> int | None:
    if path.name == base.name:
        return 0
    m = re.fullmatch(re.escape(base.stem) + r"\.([1-9][0-9]*)" + re.escape(base.suffix), path.name)
    return int(m.group(1)) if m else None


def segment_paths(base: str | os.PathLike) -> list[Path]:
    """The existing segments of ``base`` in order (``session.mcap`` first, then ``.1``, ``.2`` ... numerically)."""
    base = Path(base)
    found = [(i, p) for p in base.parent.glob(f"{base.stem}*{base.suffix}")
             if (i := _segment_index(base, p)) is not None]
    return [p for _, p in sorted(found)]


def next_segment_path(base: str | os.PathLike) -> tuple[int, Path]:
    """The first unused segment index and its path: a restarted recorder continues, never overwrites."""
    base = Path(base)
    existing = segment_paths(base)
    index = 0 if not existing else _segment_index(base, existing[-1]) + 1
    return index, segment_path(base, index)


# -- writer -------------------------------------------------------------------------------------------------------------

class LogWriter:
    """Writes one run's log: an MCAP file (or several segments), chunked, zstd.

    ``write(key, data)`` takes a concrete protocol key and either encoded bytes (written as received; the
    recorder does not re-validate) or a message object (encoded, which validates). Unknown keys raise
    ``ProtocolError('unknown_key')``. Thread-safe. Use as a context manager or call ``finish()`` in finally.
    """

    def __init__(self, path: str | os.PathLike, run_config: RunConfig, *, chunk_size: int = 1 << 20,
                 flush_interval: float = 1.0, compression: str = "zstd", max_segment_bytes: int | None = None,
                 background_flush: bool = True):
        self.base = Path(path)
        self.run_config = run_config
        self._config_bytes = run_config.encode()  # validates
        self.chunk_size, self.flush_interval = chunk_size, flush_interval
        self.compression = _COMPRESSION[compression]
        self.max_segment_bytes = max_segment_bytes
        self.paths: list[Path] = []
        self.counters: collections.Counter[str] = collections.Counter()
        self._lock = threading.RLock()
        self._dirty = False
        self._last_flush = time.monotonic()
        self._finished = False
        self.base.parent.mkdir(parents=True, exist_ok=True)
        self._open_segment()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if background_flush:
            self._thread = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
            self._thread.start()

    # segments
    def _open_segment(self) -> None:
        index, path = next_segment_path(self.base)
        self.segment = index
        self._file = open(path, "xb")  # never overwrite
        self.paths.append(path)
        self._writer = Writer(self._file, chunk_size=self.chunk_size, compression=self.compression)
        self._writer.start(profile=PROFILE, library=f"hitl-tamer protocol {PROTOCOL_VERSION}")
        self._schemas: dict[type, int] = {}
        self._channels: dict[str, int] = {}
        self._writer.add_metadata(METADATA_NAME, {
            "run": self.run_config.run, "protocol": str(PROTOCOL_VERSION), "segment": str(index),
            "run_config": self._config_bytes.decode("utf-8"),
        })
        self._write_locked(config_key(self.run_config.run), self._config_bytes, time.time_ns(), None)
        self._flush_locked()
        self.counters["segments"] += 1

    @property
    def path(self) -> Path:
        """The segment being written."""
        return self.paths[-1]

    def _channel(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is None:
            cls = parse_key(key).spec.message
            sid = self._schemas.get(cls)
            if sid is None:
                sid = self._writer.register_schema(cls.TYPE_NAME, "jsonschema",
                                                   json.dumps(cls.json_schema(), indent=None).encode())
                self._schemas[cls] = sid
            cid = self._writer.register_channel(key, cls.MESSAGE_ENCODING, sid,
                                                {"message_type": cls.__name__, "content_type": cls.CONTENT_TYPE})
            self._channels[key] = cid
        return cid

    # writing
    def write(self, key: str, data: Any, *, log_time: int | None = None, publish_time: int | None = None) -> None:
        """Append one record. ``log_time``/``publish_time`` in ns since the epoch (default: now / log_time)."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            data = data.encode()
        parse_key(key)
        with self._lock:
            if self._finished:
                raise RuntimeError("LogWriter is finished")
            self._write_locked(key, bytes(data), time.time_ns() if log_time is None else log_time, publish_time)
            if time.monotonic() - self._last_flush >= self.flush_interval:
                self._flush_locked()
            if self.max_segment_bytes is not None and self._file.tell() >= self.max_segment_bytes:
                self._finish_segment()
                self._open_segment()

    def _write_locked(self, key: str, data: bytes, log_time: int, publish_time: int | None) -> None:
        cid = self._channel(key)
        self._writer.add_message(cid, log_time=log_time, data=data,
                                 publish_time=log_time if publish_time is None else publish_time,
                                 sequence=self.counters["messages"] & 0xFFFFFFFF)
        self.counters["messages"] += 1
        self.counters["bytes"] += len(data)
        self._dirty = True

    def flush(self) -> None:
        """Close the current chunk and push everything to the OS (survives a SIGKILL; not an fsync)."""
        with self._lock:
            if not self._finished:
                self._flush_locked()

    def _flush_locked(self) -> None:
        self._writer.flush()
        self._dirty = False
        self._last_flush = time.monotonic()
        self.counters["flushes"] += 1

    def _flush_loop(self) -> None:
        period = max(0.02, self.flush_interval / 4)
        while not self._stop.wait(period):
            with self._lock:
                if self._finished:
                    return
                if self._dirty and time.monotonic() - self._last_flush >= self.flush_interval:
                    self._flush_locked()

    def _finish_segment(self) -> None:
        self._writer.finish()
        self._file.close()

    def finish(self) -> None:
        """Write the summary and close. Idempotent. Call in finally."""
        self._stop.set()
        with self._lock:
            if self._finished:
                return
            self._finished = True
            try:
                self._finish_segment()
            finally:
                if not self._file.closed:
                    self._file.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5)

    close = finish

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.finish()


# -- reader -------------------------------------------------------------------------------------------------------------

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
    chunks: int = 0
    data_complete: bool = False  # the DataEnd record was read: no message lost
    complete: bool = False  # the footer was read: a properly finished file
    error: str | None = None  # what stopped the reading, for an incomplete file


@dataclasses.dataclass
class ReadStatus:
    files: list[FileStatus] = dataclasses.field(default_factory=list)
    messages: int = 0
    undecodable: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    duplicate_configs_skipped: int = 0
    duplicates_skipped: collections.Counter = dataclasses.field(default_factory=collections.Counter)  # by kind

    @property
    def complete(self) -> bool:
        return all(f.complete for f in self.files)

    @property
    def truncated(self) -> list[str]:
        """Files whose data section was cut short (messages after the last complete chunk are lost)."""
        return [f.path for f in self.files if not f.data_complete]

    def summary(self) -> str:
        parts = [f"{self.messages} messages from {len(self.files)} file(s)"]
        for f in self.files:
            if not f.data_complete:
                parts.append(f"{f.path}: truncated, recovered {f.messages} messages in {f.chunks} complete chunks "
                             f"({f.bytes_read} of {f.size} bytes; {f.error})")
            elif not f.complete:
                parts.append(f"{f.path}: all data read, summary missing ({f.error})")
        if self.undecodable:
            parts.append(f"undecodable: {dict(self.undecodable)}")
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
        with open(path, "rb") as f:
            records = StreamReader(f, emit_chunks=True, validate_crcs=True, record_size_limit=1 << 30).records
            while True:
                try:
                    record = next(records)
                    # A chunk is read whole or not at all; its records are checked against its CRC.
                    inner = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
                except StopIteration:
                    break
                except Exception as e:  # EndOfFile, struct.error, CRC, zstd: the tail is cut or damaged
                    fs.error = f"{type(e).__name__}: {str(e)[:120]}"
                    break
                fs.bytes_read = f.tell()
                if isinstance(record, Chunk):
                    fs.chunks += 1
                for r in inner:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                        self.schemas[r.name] = r
                    elif isinstance(r, Channel):
                        channels[r.id] = r
                    elif isinstance(r, Metadata):
                        self.metadata.append((r.name, dict(r.metadata)))
                    elif isinstance(r, DataEnd):
                        fs.data_complete = True
                    elif isinstance(r, Footer):
                        fs.complete = True
                    elif isinstance(r, McapMessage):
                        out = self._record(segment, r, channels)
                        if out is not None:
                            fs.messages += 1
                            self.status.messages += 1
                            yield out
        if not fs.data_complete:
            warnings.warn(f"{path}: incomplete log, recovered {fs.messages} messages in {fs.chunks} complete "
                          f"chunks ({fs.bytes_read} of {fs.size} bytes); the rest is lost ({fs.error})",
                          LogRecoveryWarning, stacklevel=3)

    def _record(self, segment: int, m: McapMessage, channels: dict[int, Channel]) -> LogRecord | None:
        channel = channels.get(m.channel_id)
        key = channel.topic if channel is not None else f"<channel {m.channel_id}>"
        message, error = None, None
        if self.decode_messages:
            try:
                message = decode(key, m.data)
            except ProtocolError as e:
                error = e
                self.status.undecodable[e.reason] += 1
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
    from common.protocol import EpisodeSummary, Feedback, Ingest, Log, Step, Weights

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
    if isinstance(message, Log):
        return ("log", message.name, message.timestamp.sec, message.timestamp.nsec, message.message)
    return None


def read_log(path: str | os.PathLike | Iterable[str | os.PathLike], *, decode: bool = True,
             segments: bool = True, dedup: bool = True) -> LogReader:
    """Records of a log in file order.

    ``path``: a file (with ``segments=True``, also its later segments ``<stem>.1<suffix>``, ... as one log),
    a directory (its ``session.mcap`` segments), or a list of files read in the given order.
    ``decode``: decode each payload by its key (failures are counted in ``status.undecodable`` and the record
    is still yielded with ``error`` set). Later segments' copies of the same run config are skipped.
    ``dedup`` (with ``decode``): a message published twice (the same :func:`identity`: re-sent to a restarted
    recorder) is yielded once, the first time; ``status.duplicates_skipped`` counts the others by kind.
    """
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
