"""MCAP logs: schemas and metadata, crash recovery from truncated files and SIGKILL, segments as one log."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest
from mcap.reader import make_reader

from common.logs.mcap_log import (
    LogRecoveryWarning,
    LogWriter,
    load_log,
    next_segment_path,
    read_log,
    segment_path,
    segment_paths,
)
from common.protocol import (
    CompressedImage,
    Feedback,
    ProtocolError,
    RunConfig,
    ServiceStatus,
    Step,
    Weights,
    camera_key,
    config_key,
    feedback_key,
    status_key,
    step_key,
    weights_key,
)

from .strategies import example

RUN = "r1"
CONFIG = RunConfig.create(RUN, {"env": "maze", "algo": "dqn-tamer", "lr": 0.001}, t_created=1700000000.0)


def write_sample_log(path: Path, n_steps: int = 5, **kwargs) -> LogWriter:
    with LogWriter(path, CONFIG, **kwargs) as w:
        for i in range(n_steps):
            w.write(step_key(RUN), example(Step, seq=i).encode(), log_time=1_000 + i)
        w.write(feedback_key(RUN, "oracle"), example(Feedback))
        w.write(weights_key(RUN), example(Weights).encode())
        w.write(camera_key(RUN, "cam0"), example(CompressedImage))
        w.write(status_key(RUN, "learner"), example(ServiceStatus))
    return w


def test_write_then_read_with_schemas_and_metadata(tmp_path):
    path = tmp_path / "session.mcap"
    write_sample_log(path)
    reader = read_log(path)
    records = list(reader)
    assert reader.status.complete and reader.status.messages == 10 and not reader.status.truncated
    assert records[0].key == config_key(RUN) and records[0].message == CONFIG
    assert reader.run_config == CONFIG
    assert [r.message.seq for r in records if isinstance(r.message, Step)] == list(range(5))
    assert [r.log_time for r in records[1:6]] == [1000, 1001, 1002, 1003, 1004]
    assert [type(r.message).__name__ for r in records[6:]] == [
        "Feedback",
        "Weights",
        "CompressedImage",
        "ServiceStatus",
    ]
    assert records[7].message.same_as(example(Weights))
    assert (records[1].key, records[1].data) == (step_key(RUN), example(Step, seq=0).encode())
    name, meta = reader.metadata[0]
    assert name == "hitl.run" and meta["run"] == RUN and meta["segment"] == "0"
    assert RunConfig.decode(meta["run_config"].encode()) == CONFIG

    # The file is a proper MCAP with a summary: the seeking reader sees schemas and channels.
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == {
        "hitl.RunConfig",
        "hitl.Step",
        "hitl.Feedback",
        "hitl.Weights",
        "foxglove.CompressedImage",
        "hitl.ServiceStatus",
    }
    assert all(s.encoding == "jsonschema" for s in schemas.values())
    assert json.loads(schemas["hitl.Step"].data) == Step.json_schema()
    assert json.loads(schemas["hitl.Weights"].data)["x-message-encoding"] == "safetensors"
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {"/config", "/step", "/feedback/oracle", "/weights", "/camera/cam0", "/status/learner"}
    assert channels["/weights"].message_encoding == "safetensors"
    assert channels["/step"].message_encoding == "json"
    assert summary.statistics.message_count == 10
    assert summary.statistics.chunk_count >= 1


def test_unknown_key_is_refused_and_undecodable_bytes_are_counted(tmp_path):
    path = tmp_path / "session.mcap"
    with LogWriter(path, CONFIG) as w:
        with pytest.raises(ProtocolError) as e:
            w.write("hitl/r1/nope", b"{}")
        assert e.value.reason == "unknown_key"
        w.write(step_key(RUN), b"{broken")  # the recorder logs what it received, as received
    records, status = load_log(path)
    assert status.undecodable == {"malformed": 1}
    assert records[-1].message is None and records[-1].error.reason == "malformed" and records[-1].data == b"{broken"
    raw, _ = load_log(path, decode=False)
    assert all(r.message is None for r in raw)


def test_truncated_copies_recover_every_complete_chunk(tmp_path):
    path = tmp_path / "session.mcap"
    with LogWriter(path, CONFIG, background_flush=False) as w:
        for i in range(30):
            w.write(step_key(RUN), example(Step, seq=i).encode())
            if i % 10 == 9:
                w.flush()  # one chunk per 10 steps (plus the config's own chunk)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    seen_counts = set()
    previous = 0
    for n in range(0, len(data) + 1, 11):
        cut.write_bytes(data[:n])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            reader = read_log(cut, segments=False)
            records = list(reader)
        steps = [r.message.seq for r in records if isinstance(r.message, Step)]
        assert steps == list(range(len(steps)))  # a prefix, in order
        assert len(steps) in (0, 10, 20, 30)  # whole chunks only
        assert len(records) >= previous
        previous = len(records)
        seen_counts.add(len(steps))
        status = reader.status.files[0]
        if not status.data_complete:
            assert any(issubclass(c.category, LogRecoveryWarning) for c in caught)
            assert reader.status.truncated == [str(cut)]
            assert status.bytes_read <= n and status.error
    assert seen_counts == {0, 10, 20, 30}


def chunk_ends(path: Path) -> list[int]:
    from mcap.exceptions import EndOfFile
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    ends = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    ends.append(f.tell())
        except EndOfFile:  # an unfinished file ends without a footer
            pass
    return ends


def test_truncated_file_cannot_be_opened_with_make_reader_but_read_log_recovers(tmp_path):
    path = tmp_path / "session.mcap"
    w = LogWriter(path, CONFIG, background_flush=False)
    for i in range(20):
        w.write(step_key(RUN), example(Step, seq=i).encode())
        if i in (9, 19):
            w.flush()
    w._file.close()  # a crash: no finish()
    ends = chunk_ends(path)
    assert len(ends) == 3  # the config's chunk, then two chunks of ten steps
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: ends[-1] - 20])  # and the last chunk cut short
    with open(cut, "rb") as f, pytest.raises(Exception):  # noqa: B017  (whatever the mcap library raises)
        list(make_reader(f).iter_messages())
    with pytest.warns(LogRecoveryWarning, match="recovered 11 messages"):
        records, status = load_log(cut)
    assert [r.message.seq for r in records[1:]] == list(range(10))
    assert "truncated" in status.summary() and not status.complete


def test_background_flush_makes_pending_messages_durable_within_a_second(tmp_path):
    path = tmp_path / "session.mcap"
    w = LogWriter(path, CONFIG, flush_interval=0.3)
    try:
        w.write(step_key(RUN), example(Step, seq=0).encode())
        time.sleep(1.0)  # no further write: only the background thread can flush
        snapshot = tmp_path / "snap.mcap"
        shutil.copyfile(path, snapshot)
        with pytest.warns(LogRecoveryWarning):
            records, _ = load_log(snapshot, segments=False)
        assert [type(r.message) for r in records] == [RunConfig, Step]
    finally:
        w.finish()


def test_background_flush_sleeps_while_quiet_and_wakes_for_the_next_write(tmp_path):
    """The flush thread sleeps while nothing is pending (no periodic look), and a write after a quiet spell
    is still flushed by it within the interval."""
    path = tmp_path / "session.mcap"
    w = LogWriter(path, CONFIG, flush_interval=0.2)
    try:
        w.write(step_key(RUN), example(Step, seq=0).encode())
        time.sleep(0.6)
        after_first, passes = w.counters["flushes"], w.counters["flush_thread_passes"]
        time.sleep(0.6)  # quiet: nothing to flush, and the thread does not even look
        assert w.counters["flushes"] == after_first >= 1
        assert w.counters["flush_thread_passes"] == passes
        w.write(step_key(RUN), example(Step, seq=1).encode())
        time.sleep(0.6)  # only the (sleeping) thread can flush this one
        assert w.counters["flushes"] == after_first + 1
        snapshot = tmp_path / "snap.mcap"
        shutil.copyfile(path, snapshot)
        with pytest.warns(LogRecoveryWarning):
            records, _ = load_log(snapshot, segments=False)
        assert [getattr(r.message, "seq", None) for r in records] == [None, 0, 1]
    finally:
        w.finish()


@pytest.mark.timeout(60)
def test_sigkill_loses_at_most_about_one_second(tmp_path):
    path = tmp_path / "session.mcap"
    proc = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("mcap_writer_proc.py")), str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    written: list[tuple[int, float]] = []
    try:
        # (a line cut by the kill is not a report of a write)
        reader = threading.Thread(
            target=lambda: [
                written.append((int(f[0]), float(f[1]))) for f in (line.split() for line in proc.stdout) if len(f) == 2
            ],
            daemon=True,
        )
        reader.start()
        deadline = time.monotonic() + 20
        while (not written or written[-1][1] - written[0][1] < 2.5) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert written, proc.stderr.read() if proc.poll() is not None else "no output"
        t_kill = time.time()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        reader.join(5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    with pytest.warns(LogRecoveryWarning):
        records, status = load_log(path)
    seqs = [r.message.seq for r in records if isinstance(r.message, Step)]
    assert seqs == list(range(len(seqs)))
    durable_by = [seq for seq, t in written if t <= t_kill - 1.5]  # written more than 1.5 s before the kill
    assert durable_by and len(seqs) > durable_by[-1], (len(seqs), durable_by[-1], len(written))
    assert status.truncated == [str(path)]


def test_segments_by_size_read_as_one_log(tmp_path):
    base = tmp_path / "session.mcap"
    with LogWriter(base, CONFIG, max_segment_bytes=1500, background_flush=False) as w:
        for i in range(60):
            w.write(step_key(RUN), example(Step, seq=i).encode())
            if i % 5 == 4:
                w.flush()
    assert len(w.paths) >= 3 and w.paths == segment_paths(base)
    assert w.paths[1] == segment_path(base, 1) == tmp_path / "session.1.mcap"
    reader = read_log(base)
    records = list(reader)
    assert [r.message.seq for r in records if isinstance(r.message, Step)] == list(range(60))
    assert sum(isinstance(r.message, RunConfig) for r in records) == 1
    assert reader.status.duplicate_configs_skipped == len(w.paths) - 1
    assert [r.segment for r in records] == sorted(r.segment for r in records)
    assert [m["segment"] for _, m in reader.metadata] == [str(i) for i in range(len(w.paths))]
    assert reader.status.complete
    # each segment is a complete MCAP on its own
    for p in w.paths:
        with open(p, "rb") as f:
            assert make_reader(f).get_summary().statistics.message_count >= 1


def test_restarted_writer_continues_in_a_new_segment_and_crashed_segment_is_recovered(tmp_path):
    base = tmp_path / "session.mcap"
    crashed = LogWriter(base, CONFIG, background_flush=False)
    for i in range(3):
        crashed.write(step_key(RUN), example(Step, seq=i).encode())
    crashed.flush()
    crashed._file.close()  # simulate a crash: no finish(), no summary
    assert next_segment_path(base) == (1, tmp_path / "session.1.mcap")
    with LogWriter(base, CONFIG) as again:
        assert again.path == tmp_path / "session.1.mcap"
        again.write(step_key(RUN), example(Step, seq=3, incarnation="actor-2").encode())
    (tmp_path / "session.x.mcap").write_bytes(b"not a segment")
    (tmp_path / "session.10.mcap.bak").write_bytes(b"not a segment")
    assert segment_paths(base) == [base, tmp_path / "session.1.mcap"]
    with pytest.warns(LogRecoveryWarning, match="session.mcap: incomplete"):
        records, status = load_log(tmp_path)  # a directory: its session segments
    assert [r.message.seq for r in records if isinstance(r.message, Step)] == [0, 1, 2, 3]
    assert status.truncated == [str(base)] and status.files[1].complete


def test_writer_never_overwrites_and_is_thread_safe(tmp_path):
    base = tmp_path / "session.mcap"
    base.write_bytes(b"precious")
    w = LogWriter(base, CONFIG, flush_interval=0.01)
    try:
        threads = [
            threading.Thread(
                target=lambda k=k: [w.write(step_key(RUN), example(Step, seq=i).encode()) for i in range(200)]
            )
            for k in range(4)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        w.finish()
        w.finish()  # idempotent
    assert base.read_bytes() == b"precious" and w.path.name == "session.1.mcap"
    records, status = load_log(w.path, segments=False, dedup=False)  # the same 200 steps 4 times
    assert status.complete and len(records) == 801
    with pytest.raises(RuntimeError):
        w.write(step_key(RUN), b"{}")
    os.remove(base)
