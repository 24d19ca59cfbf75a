"""Damaged and wrong files: a corrupt chunk is skipped and every other chunk is read; a file that is not MCAP
is refused with one line and a non-zero exit. What each chunk holds is worked out with the `mcap` package's
own stream reader on the intact file, not with the project's reader."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from common.logs.mcap_log import LogRecoveryWarning, LogWriter, NotMcapError, read_log
from common.protocol import RunConfig, Step, feedback_key, step_key, Feedback

from .strategies import example

RUN = "dmg"
ROOT = Path(__file__).resolve().parents[2]


def write_log(path: Path, n: int = 600) -> None:
    config = RunConfig.create(RUN, {"env": "maze"}, t_created=1700000000.0)
    with LogWriter(path, config, chunk_size=4096, background_flush=False) as w:
        for i in range(n):
            w.write(step_key(RUN), example(Step, run=RUN, seq=i).encode(), log_time=10_000 + i)
            if i % 7 == 0:
                w.write(feedback_key(RUN, "oracle"), example(Feedback, run=RUN, seq=i // 7), log_time=10_000 + i)


def chunks_of(path: Path) -> list[tuple[int, int, list[bytes]]]:
    """(offset, record length, message payloads) of every chunk, by the mcap package's stream reader."""
    out = []
    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True)
        records = reader.records
        while True:
            start = f.tell()  # StreamReader reads the file object exactly, record by record
            try:
                record = next(records)
            except StopIteration:
                break
            if isinstance(record, Chunk):
                msgs = [r.data for r in breakup_chunk(record) if isinstance(r, Message)]
                out.append((start, f.tell() - start, msgs))
    return out


def payloads(path: Path) -> tuple[list[bytes], object]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = read_log(path, segments=False, decode=False)
        got = [r.data for r in reader]
    return got, reader.status, [w for w in caught if issubclass(w.category, LogRecoveryWarning)]


@pytest.mark.parametrize("which", ["first", "middle", "last"])
def test_flipped_bytes_inside_one_chunk_lose_only_that_chunk(tmp_path, which):
    path = tmp_path / "session.mcap"
    write_log(path)
    chunks = chunks_of(path)
    assert len(chunks) >= 10
    k = {"first": 0, "middle": len(chunks) // 2, "last": len(chunks) - 1}[which]
    offset, length, lost = chunks[k]
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(k)
    # Flip 200 bytes in the chunk's compressed records (past its fixed header fields).
    for pos in rng.choice(np.arange(offset + 60, offset + length), size=min(200, length - 60), replace=False):
        data[pos] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))

    got, status, warned = payloads(damaged)
    expected = [m for i, (_, _, msgs) in enumerate(chunks) if i != k for m in msgs]
    assert got == expected  # every message of every other chunk, in order
    f = status.files[0]
    assert f.chunks_lost == 1 and f.messages_lost == len(lost) and f.chunks == len(chunks) - 1
    assert f.data_complete and f.complete  # read on to the end of the file
    assert warned and "skipped 1 damaged chunk" in str(warned[-1].message)
    assert f"{len(lost)} messages lost" in status.summary()


def test_damaged_chunk_header_resyncs_on_the_next_good_chunk(tmp_path):
    path = tmp_path / "session.mcap"
    write_log(path)
    chunks = chunks_of(path)
    k = len(chunks) // 3
    offset, length, lost = chunks[k]
    data = bytearray(path.read_bytes())
    data[offset + 1 : offset + 9] = (2**62).to_bytes(8, "little")  # the chunk's record length: runs past the end
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    got, status, _ = payloads(damaged)
    assert got == [m for i, (_, _, msgs) in enumerate(chunks) if i != k for m in msgs]
    assert status.files[0].chunks_lost == 1 and status.files[0].complete


def test_cut_file_with_a_damaged_chunk_reads_the_good_chunks_up_to_the_cut(tmp_path):
    path = tmp_path / "session.mcap"
    write_log(path)
    chunks = chunks_of(path)
    offset, length, _ = chunks[2]
    cut_at = chunks[-3][0] + chunks[-3][1] // 2
    data = bytearray(path.read_bytes()[:cut_at])
    data[offset + length // 2] ^= 0x55
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(bytes(data))
    got, status, _ = payloads(damaged)
    assert got == [m for i, (_, _, msgs) in enumerate(chunks[:-3]) if i != 2 for m in msgs]
    f = status.files[0]
    assert f.chunks_lost == 1 and not f.data_complete and f.error.startswith("EndOfFile")


def mp4_file(path: Path) -> Path:
    import cv2

    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (64, 48))
    assert out.isOpened()
    for i in range(10):
        out.write(np.full((48, 64, 3), i * 20, np.uint8))
    out.release()
    assert path.read_bytes()[4:8] == b"ftyp"  # a real MP4 container
    return path


@pytest.mark.parametrize("kind", ["random", "mp4"])
def test_a_file_that_is_not_mcap_is_refused_in_one_line_with_a_nonzero_exit(tmp_path, kind):
    if kind == "random":
        bad = tmp_path / "random.mcap"
        bad.write_bytes(np.random.default_rng(0).integers(0, 256, 100_000, dtype=np.uint8).tobytes())
    else:
        bad = mp4_file(tmp_path / "clip.mp4")
    with pytest.raises(NotMcapError):
        list(read_log(bad))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", "services.replay", str(bad), "summary", "--no-plot"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not an MCAP file" in lines[0], proc.stderr
    assert proc.stdout == ""


def replay_summary(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "services.replay", *args, "summary", "--no-plot"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


def test_summary_of_a_log_with_one_flipped_byte_exits_nonzero_and_names_what_was_lost(tmp_path):
    """Issue 25, finding 5: one flipped byte used to print "(complete)" and exit 0 while a chunk's messages
    were skipped."""
    path = tmp_path / "session.mcap"
    write_log(path)
    chunks = chunks_of(path)
    offset, length, lost = chunks[len(chunks) // 2]
    data = bytearray(path.read_bytes())
    data[offset + length // 2] ^= 0x01  # one bit of one byte inside the chunk's compressed records
    path.write_bytes(bytes(data))
    whole = sum(len(msgs) for _, _, msgs in chunks)
    proc = replay_summary(str(path))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "(complete)" not in proc.stdout and "DATA LOST" in proc.stdout, proc.stdout
    lost_lines = [line for line in proc.stdout.splitlines() if line.strip().startswith("lost:")]
    assert len(lost_lines) == 1, proc.stdout
    assert f"skipped 1 damaged chunk(s), {length} bytes, {len(lost)} messages" in lost_lines[0]
    assert f"offset {offset}" in lost_lines[0]
    assert f"{whole - len(lost)} messages read" in proc.stdout
    assert replay_summary(str(tmp_path)).returncode == 1  # the run directory: the same log
    path.write_bytes(bytes(data[: offset + length // 2]))  # cut inside that chunk: truncated, also named
    proc = replay_summary(str(path))
    assert proc.returncode == 1 and "truncated" in proc.stdout, proc.stdout


def test_summary_of_an_intact_log_exits_zero(tmp_path):
    write_log(tmp_path / "session.mcap")
    proc = replay_summary(str(tmp_path / "session.mcap"))
    assert proc.returncode == 0 and "(complete)" in proc.stdout and "lost:" not in proc.stdout, proc.stdout


@pytest.mark.parametrize("kind", ["empty", "directory", "missing"])
def test_summary_of_no_log_is_one_line_and_exit_2(tmp_path, kind):
    target = {"empty": tmp_path / "session.mcap", "directory": tmp_path / "somedir", "missing": tmp_path / "nope.mcap"}[
        kind
    ]
    if kind == "empty":
        target.write_bytes(b"")
    elif kind == "directory":
        target.mkdir()
        (target / "notes.txt").write_text("not a log")
    proc = replay_summary(str(target))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stdout == "" and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {target}: "), proc.stderr
