"""`python -m services.recorder`: everything under `hitl/<run>/**` that the log keeps (all but the weights) into
one MCAP file.

Just another subscriber: samples are written as received (bytes untouched, log time = arrival, publish time
= the sample's Zenoh timestamp), one channel per key, one schema per type, zstd chunks flushed every
`flush_interval` s (so a killed recorder loses at most that much). The log's run config (its metadata and
first message) is the JSON object in `run_config` (the launcher writes the whole run's settings there) or
this recorder's own config. Stops on SIGTERM/SIGINT, or once every service in `stop_when` has reported
'stopped' (plus `linger` s for stragglers).

Every sample is decoded (validated) before it is written: what does not decode (malformed, oversized, wrong
types, NaN, a key the protocol does not know...) is dropped and counted (`rejected_<reason>`), so the log holds
only valid messages. A restarted recorder opens the next segment (`session.1.mcap`, ...); the publishers
re-send their last seconds to it, so a reader of all segments (`read_log`, which drops the duplicates) gets
what the killed recorder had not flushed.
"""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any

from common.config import config_record
from common.protocol import KEYS, ProtocolError, RunConfig, ServiceStatus, decode, status_key
from common.logs.scene import SceneBuilder, derived_records, scene_available
from services.common.config import RecorderConfig
from services.common.gate import first_time_logger
from services.common.watches import AliveWatch
from services.common.runtime import ServiceRuntime, service_main
from services.recorder.caps import RecordCaps

MIB = 1 << 20


def load_run_config(config: RecorderConfig) -> RunConfig:
    if config.run_config:
        with open(config.run_config) as fh:
            payload = json.load(fh)
        if not isinstance(payload, dict):
            raise ValueError(f"{config.run_config}: expected a JSON object")
    else:
        payload = {"recorder": config_record(config)}
    return RunConfig.create(config.run, payload)


# How long the loop waits for a message before it looks at its clock (its status, a stop, the others' tokens): while
# it lingers at the end, briefly; otherwise until the next status is due, at most IDLE_PASS s (a stop then takes
# effect within that). It waited 0.05 s, 20 wake-ups a second while nothing happened.
LINGER_PASS = 0.05
IDLE_PASS = 0.25


def idle_wait(rt: ServiceRuntime) -> float:
    return max(LINGER_PASS, min(IDLE_PASS, rt.status_due_in()))


def write_message(item, writer, caps: RecordCaps, scene, rt: ServiceRuntime, note_rejected) -> Any | None:
    """One received message into the log (within the caps, checked) with the records it derives (Credits, the
    scene); the decoded message, or None where it was dropped (counted)."""
    try:
        st = decode(item.key, item.data)
        if not caps.admit(item.key, len(item.data)):
            rt.counters[f"capped_{item.key.split('/')[2]}"] += 1
            return None
        t_log = int(item.t_recv * 1e9)
        writer.write(item.key, item.data, log_time=t_log, publish_time=int((item.t_zenoh or item.t_recv) * 1e9))
    except ProtocolError as e:
        rt.counters[f"rejected_{e.reason}"] += 1
        note_rejected(e.reason, item.key[:80])
        return None
    for key, data in derived_records(rt.config.run, st, scene, rt.counters):
        writer.write(key, data, log_time=t_log)
    return st


def write_own_stop(writer, run: str, rt: ServiceRuntime) -> None:
    """The recorder's own last word, straight into the file (its subscription is closing)."""
    counters = dict(sorted(rt.all_counters().items())[:256])
    stopped = ServiceStatus(
        run=run, service=rt.name, pid=os.getpid(), state="stopped", t=time.time(), counters=counters
    )
    writer.write(status_key(run, rt.name), stopped)


def main(config: RecorderConfig) -> int:
    from common.logs.mcap_log import LogWriter
    from common.wire.transport import subscriptions

    rt = ServiceRuntime("recorder", config)
    run_config = load_run_config(config)
    writer = LogWriter(config.out, run_config, flush_interval=config.flush_interval)
    scene = SceneBuilder.from_run_config(run_config.config)  # the environment drawn for Foxglove (docs/logs.md)
    if not scene_available():
        print("recorder: the log gets no Foxglove scene (pip install 'hitl-tamer[foxglove]' adds it)", file=sys.stderr)
    rt.set_counters_source(
        lambda: {"messages_written": writer.counters["messages"], "bytes_written": writer.counters["bytes"]}
    )
    stopped: set[str] = set()
    caps = RecordCaps(config.max_sender_mb_s * MIB, config.max_camera_mb_s * MIB, config.max_camera_fps)
    try:
        with rt.session() as session:
            # What it logs, kind by kind: not `hitl/<run>/**`, which would bring it the weights the actor needs
            # after almost every step (KEYS["weights"].logged is False) only to drop them.
            logged = [spec.wildcard(config.run) for spec in KEYS.values() if spec.logged]
            with subscriptions(session, logged, maxsize=1 << 16, policy="block", block_timeout=3600) as inbox:
                rt.ready()
                note_rejected = first_time_logger(rt.event, "message")
                others = None
                if writer.segment > 0:
                    rt.event(f"recorder restarted: writing segment {writer.segment} ({writer.path})", 3)
                    if config.stop_when:  # they may have stopped while we were down: watch their tokens
                        others = AliveWatch(session, config.run, config.stop_when)
                t_ready = time.monotonic()
                linger_until: float | None = None
                while True:
                    if rt.stop.is_set() and linger_until is None:
                        linger_until = time.monotonic() + min(config.linger, 0.2)
                    if linger_until is not None and time.monotonic() >= linger_until and len(inbox) == 0:
                        break
                    item = inbox.get(timeout=LINGER_PASS if linger_until is not None else idle_wait(rt))
                    st = write_message(item, writer, caps, scene, rt, note_rejected) if item is not None else None
                    if st is not None:
                        if config.stop_when and isinstance(st, ServiceStatus) and st.state == "stopped":
                            stopped.add(st.service)
                            if linger_until is None and set(config.stop_when) <= stopped:
                                linger_until = time.monotonic() + config.linger
                    if (
                        others is not None
                        and linger_until is None
                        and time.monotonic() - t_ready > 3.0
                        and not others.alive
                        and all(time.monotonic() - others.gone_since.get(n, t_ready) > 1.0 for n in config.stop_when)
                    ):
                        rt.log(f"none of {', '.join(config.stop_when)} is alive any more: the run is over")
                        linger_until = time.monotonic() + config.linger
                    rt.tick()
                if others is not None:
                    others.close()
                rt.counters.update({f"inbox_{k}": v for k, v in inbox.snapshot().items()})
                write_own_stop(writer, config.run, rt)
    finally:
        writer.finish()
    rt.write_stats(paths=[str(p) for p in writer.paths])
    rt.log(f"stopped: {writer.counters['messages']} messages in {', '.join(str(p) for p in writer.paths)}")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return service_main(RecorderConfig, main, argv, "python -m services.recorder")
