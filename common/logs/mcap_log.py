"""MCAP logs of a run: one writer that a recorder (or any service) feeds with (key, bytes); the reader
(``read_log``, in ``common/logs/mcap_read.py``) gives the records back in file order, also from files cut short
by a crash or with damaged chunks, and from several segment files (``session.mcap``, ``session.1.mcap``, ...).

Layout of every segment file:

- MCAP metadata ``hitl.run``: ``run``, ``protocol``, ``segment``, ``run_config`` (the RunConfig message as
  JSON);
- the first message: the RunConfig on topic ``/config``;
- then one channel per key expression, its topic the key without ``hitl/<run>`` (``/step``,
  ``/feedback/<teacher>``: the same in every run, so a Foxglove layout fits any log; docs/logs.md), one
  schema per message type (name = the type's ``TYPE_NAME``; JSON types: encoding ``jsonschema``, data = its
  JSON Schema; Foxglove's scene types: encoding ``protobuf``, data = their FileDescriptorSet), messages in
  arrival order, zstd chunks.

The writer finishes its chunk and flushes the file at least every ``flush_interval`` (1 s) while data
is pending (a background thread does it when no new message arrives), so a SIGKILL loses at most about
that much.
"""

from __future__ import annotations

import collections
import json
import os
import re
import threading
import time
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from common.logs.mcap_read import (  # noqa: F401  (re-exported: the log's one import for readers and writers)
    CHANNEL_METADATA,
    METADATA_NAME,
    FileStatus,
    LogReader,
    LogRecord,
    LogRecoveryWarning,
    NotMcapError,
    ReadStatus,
    identity,
    load_log,
    read_log,
)
from common.protocol import PROTOCOL_VERSION, RunConfig, config_key, log_topic, parse_key

PROFILE = "hitl"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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
    found = [
        (i, p) for p in base.parent.glob(f"{base.stem}*{base.suffix}") if (i := _segment_index(base, p)) is not None
    ]
    return [p for _, p in sorted(found)]


def next_segment_path(base: str | os.PathLike) -> tuple[int, Path]:
    """The first unused segment index and its path: a restarted recorder continues, never overwrites."""
    base = Path(base)
    existing = segment_paths(base)
    index = 0 if not existing else _segment_index(base, existing[-1]) + 1
    return index, segment_path(base, index)


def schema_record(cls: type) -> tuple[str, bytes]:
    """(schema encoding, schema data) of a message type: its JSON Schema, or what the type says it has
    (Foxglove's protobuf types carry their FileDescriptorSet)."""
    if hasattr(cls, "schema_data"):
        return cls.SCHEMA_ENCODING, cls.schema_data()
    return "jsonschema", json.dumps(cls.json_schema(), indent=None).encode()


# -- writer ------------------------------------------------------------------------------------------------------------


class LogWriter:
    """Writes one run's log: an MCAP file (or several segments), chunked, zstd.

    ``write(key, data)`` takes a concrete protocol key and either encoded bytes (written as received; the
    recorder does not re-validate) or a message object (encoded, which validates). Unknown keys raise
    ``ProtocolError('unknown_key')``. Thread-safe. Use as a context manager or call ``finish()`` in finally.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        run_config: RunConfig,
        *,
        chunk_size: int = 1 << 20,
        flush_interval: float = 1.0,
        compression: str = "zstd",
        max_segment_bytes: int | None = None,
        background_flush: bool = True,
    ):
        self.base = Path(path)
        self.run_config = run_config
        self._config_bytes = run_config.encode()  # validates
        self.chunk_size, self.flush_interval = chunk_size, flush_interval
        self.compression = _COMPRESSION[compression]
        self.max_segment_bytes = max_segment_bytes
        self.paths: list[Path] = []
        self.counters: collections.Counter[str] = collections.Counter()
        self._lock = threading.RLock()
        self._wake = threading.Event()  # set by write() when the file turns dirty, and by finish()
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
        self._writer.add_metadata(
            METADATA_NAME,
            {
                "run": self.run_config.run,
                "protocol": str(PROTOCOL_VERSION),
                "segment": str(index),
                "run_config": self._config_bytes.decode("utf-8"),
            },
        )
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
                sid = self._writer.register_schema(cls.TYPE_NAME, *schema_record(cls))
                self._schemas[cls] = sid
            topic = log_topic(key)
            cid = self._writer.register_channel(
                topic, cls.MESSAGE_ENCODING, sid, {"message_type": cls.__name__, "content_type": cls.CONTENT_TYPE}
            )
            # Also outside the chunks: a reader of a crashed file whose chunk with this definition is damaged
            # still knows the channel's topic.
            self._writer.add_metadata(
                CHANNEL_METADATA,
                {"id": str(cid), "topic": topic, "schema": cls.TYPE_NAME, "message_encoding": cls.MESSAGE_ENCODING},
            )
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
        self._writer.add_message(
            cid,
            log_time=log_time,
            data=data,
            publish_time=log_time if publish_time is None else publish_time,
            sequence=self.counters["messages"] & 0xFFFFFFFF,
        )
        self.counters["messages"] += 1
        self.counters["bytes"] += len(data)
        if not self._dirty:
            self._dirty = True
            self._wake.set()

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
        # Sleeps until something is written (write() sets _wake when the file turns dirty), then until its flush
        # is due: a quiet log costs no wake-ups (it looked 4 times per flush interval before).
        while not self._stop.is_set():
            with self._lock:
                if self._finished:
                    return
                self.counters["flush_thread_passes"] += 1
                due = self._last_flush + self.flush_interval if self._dirty else None
                if due is not None and time.monotonic() >= due:
                    self._flush_locked()
                    due = None
                self._wake.clear()
            self._wake.wait(None if due is None else max(0.0, due - time.monotonic()))

    def _finish_segment(self) -> None:
        self._writer.finish()
        self._file.close()

    def finish(self) -> None:
        """Write the summary and close. Idempotent. Call in finally."""
        self._stop.set()
        self._wake.set()
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

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.finish()
