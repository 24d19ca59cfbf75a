"""Reading the records of an MCAP file that may be cut short or damaged, without giving up at the first bad byte.

The file is walked record by record (opcode, length, body), as MCAP's own stream reader does, but:

- a file that does not start with MCAP's magic bytes is refused at once (:class:`NotMcapError`), so a random
  file or a video never reads as an empty log;
- a chunk whose compressed data or CRC is bad is skipped: the walk goes on with the next record, and the
  message index records that follow the chunk say how many messages were lost (:class:`LostChunk`);
- a damaged record header (a length that runs past the end, an unknown opcode) makes the walk search forward
  for the next chunk that decompresses and passes its CRC, and go on from there;
- a finished file's summary section (schemas and channels) is read first, so messages whose channel was
  defined in a lost chunk still get their topic.

Only the ``mcap`` package's record classes are used to parse; nothing here knows our protocol.
"""

from __future__ import annotations

import dataclasses
import mmap
import struct
import zlib
from io import BytesIO
from collections.abc import Iterator

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, MessageIndex, Metadata, Schema

MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK_BYTES = 1 << 30  # a length field above this is damage, not data
_PARSERS = {
    Opcode.HEADER: Header.read,
    Opcode.FOOTER: Footer.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.MESSAGE_INDEX: MessageIndex.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.METADATA: Metadata.read,
    Opcode.DATA_END: DataEnd.read,
}
_KNOWN = {int(op) for op in Opcode}


class NotMcapError(ValueError):
    """The file is not an MCAP file (its first bytes are not MCAP's magic)."""


@dataclasses.dataclass
class LostChunk:
    offset: int  # where the chunk record starts in the file
    length: int  # bytes skipped
    messages: int | None  # messages it held, from the message index after it (None if unknown)
    start_time: int  # log time range it covered (ns), 0 if unknown
    end_time: int
    reason: str


@dataclasses.dataclass
class ScanResult:
    chunks: int = 0  # chunks read whole
    lost: list[LostChunk] = dataclasses.field(default_factory=list)
    resyncs: int = 0  # times the walk had to search for the next good chunk
    bytes_read: int = 0  # end of the last record read whole
    data_complete: bool = False
    complete: bool = False
    error: str | None = None  # why the walk stopped before the footer

    @property
    def messages_lost(self) -> int:
        return sum(c.messages or 0 for c in self.lost)


def check_magic(path) -> None:
    """Raise :class:`NotMcapError` with a one-line reason unless the file starts with MCAP's magic."""
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    # A file shorter than the magic that begins like it is a log cut at birth (read as empty), not another format.
    if head != MAGIC and not MAGIC.startswith(head):
        raise NotMcapError(f"{path}: not an MCAP file (starts with {head[:8]!r}, not MCAP's magic bytes)")


def _parse(opcode: int, body: bytes, length: int):
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, length)
    return _PARSERS[opcode](stream)


def chunk_records(chunk: Chunk) -> list:
    """The schema, channel and message records inside a chunk; raises on bad compression or CRC."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise ValueError(f"implausible uncompressed size {chunk.uncompressed_size}")
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unknown compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise ValueError(f"decompressed {len(data)} bytes, header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("CRC mismatch")
    out, pos = [], 0
    while pos < len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        pos += 9
        if pos + length > len(data):
            raise ValueError("record runs past the end of its chunk")
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
            out.append(_parse(opcode, bytes(data[pos : pos + length]), length))
        pos += length
    return out


def _summary_records(buf, size: int) -> list:
    """Schemas and channels of a finished file's summary section ([] if there is none or it is damaged)."""
    try:
        if size < 2 * len(MAGIC) + 29 or bytes(buf[size - 8 :]) != MAGIC:
            return []
        opcode, length = struct.unpack_from("<BQ", buf, size - 8 - 29)
        if opcode != Opcode.FOOTER or length != 20:
            return []
        footer = _parse(opcode, bytes(buf[size - 8 - 20 : size - 8]), 20)
        pos, end, out = footer.summary_start, size - 8 - 29, []
        if not 0 < pos < end:
            return []
        while pos + 9 <= end:
            opcode, length = struct.unpack_from("<BQ", buf, pos)
            if pos + 9 + length > end:
                return out
            if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                out.append(_parse(opcode, bytes(buf[pos + 9 : pos + 9 + length]), length))
            pos += 9 + length
        return out
    except Exception:  # a damaged summary is no summary: the data section still has everything
        return []


def _good_chunk_at(buf, pos: int, size: int) -> bool:
    if buf[pos] != Opcode.CHUNK or pos + 9 > size:
        return False
    (length,) = struct.unpack_from("<Q", buf, pos + 1)
    if length > MAX_CHUNK_BYTES or pos + 9 + length > size:
        return False
    try:
        chunk_records(_parse(Opcode.CHUNK, bytes(buf[pos + 9 : pos + 9 + length]), length))
    except Exception:
        return False
    return True


def _resync(buf, start: int, size: int) -> int | None:
    """Offset of the next chunk record after `start` that decompresses and passes its CRC, or None."""
    pos = start
    while True:
        pos = buf.find(bytes([Opcode.CHUNK]), pos, size)
        if pos < 0:
            return None
        if _good_chunk_at(buf, pos, size):
            return pos
        pos += 1


def scan(path, result: ScanResult) -> Iterator:
    """Yield the records of an MCAP file in file order (the records inside good chunks, not the chunks),
    filling `result` as it goes. Raises :class:`NotMcapError` for a file that is not MCAP."""
    check_magic(path)
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        if size <= len(MAGIC):  # mmap cannot map an empty file
            result.error = "EndOfFile: nothing after the magic bytes"
            return
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            yield from _summary_records(buf, size)
            yield from _walk(buf, size, result)


def _walk(buf, size: int, result: ScanResult) -> Iterator:
    pos = len(MAGIC)
    pending: LostChunk | None = None  # a lost chunk whose message index records are still coming
    while pos < size:
        if pos + 9 > size:
            result.error = f"EndOfFile: {size - pos} bytes of a record header at offset {pos}"
            return
        opcode, length = struct.unpack_from("<BQ", buf, pos)
        end = pos + 9 + length
        if opcode not in _KNOWN or opcode == 0 or end > size:
            nxt = _resync(buf, pos + 1, size)
            if nxt is None:
                if end > size and opcode in _KNOWN and opcode != 0:
                    result.error = f"EndOfFile: a record at offset {pos} needs {length} bytes, {size - pos - 9} left"
                else:
                    result.error = f"damaged record at offset {pos}; no good chunk after it"
                return
            result.lost.append(LostChunk(pos, nxt - pos, None, 0, 0, "damaged record header"))
            result.resyncs += 1
            pos, pending = nxt, None
            continue
        body = bytes(buf[pos + 9 : end])
        if opcode == Opcode.MESSAGE_INDEX and pending is not None:
            try:
                pending.messages = (pending.messages or 0) + len(_parse(opcode, body, length).records)
            except Exception:
                pass
            pos = end
            continue
        pending = None
        if opcode not in _PARSERS and opcode != Opcode.MESSAGE:
            pos = end  # index and statistics records: nothing to read
            continue
        try:
            record = _parse(opcode, body, length)
            inner = chunk_records(record) if opcode == Opcode.CHUNK else [record]
        except Exception as e:
            reason = f"{type(e).__name__}: {str(e)[:100]}"
            if opcode == Opcode.CHUNK:
                start, stop = struct.unpack_from("<QQ", body, 0) if len(body) >= 16 else (0, 0)
                pending = LostChunk(pos, 9 + length, None, start, stop, reason)
                result.lost.append(pending)
            else:
                result.lost.append(LostChunk(pos, 9 + length, None, 0, 0, f"{Opcode(opcode).name}: {reason}"))
            pos = end
            continue
        pos = end
        result.bytes_read = end
        if opcode == Opcode.CHUNK:
            result.chunks += 1
        elif opcode == Opcode.DATA_END:
            result.data_complete = True
        elif opcode == Opcode.FOOTER:
            result.complete = True
            return
        yield from inner
    if not result.complete and result.error is None:
        result.error = "EndOfFile: no footer"
