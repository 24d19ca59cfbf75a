"""`replay LOG play`: re-publish a recorded session over Zenoh, at the recorded pace or faster.

Every record goes back on its own key with its own bytes (so a recorder or any subscriber sees what the
live system saw), spaced by the recorded arrival times divided by `speed` (0: as fast as possible).
"""

from __future__ import annotations

import os
import time
import warnings
from typing import Any

from common.logs.mcap_log import LogRecoveryWarning, read_log
from common.protocol import ProtocolError, parse_key


def play(
    path: str | os.PathLike,
    session: Any,
    *,
    speed: float = 1.0,
    kinds: tuple[str, ...] = (),
    stop: Any = None,
    on_record: Any = None,
    signer: Any = None,
) -> dict[str, int]:
    """Publish the log's records on `session`, each signed as its original sender by `signer`
    (`common.wire.auth.SignAsSender`; receivers drop what is not signed). Returns counts by kind."""
    from common.wire.transport import declare_publisher

    publishers: dict[str, Any] = {}
    counts: dict[str, int] = {}
    t0_log = None
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("default", LogRecoveryWarning)
        for rec in read_log(path):  # decoded: what a restarted recorder got twice (re-sent) plays once
            try:
                kind = parse_key(rec.key).spec.kind
            except ProtocolError:
                continue
            if kinds and kind not in kinds:
                continue
            if stop is not None and stop.is_set():
                break
            if speed > 0:
                if t0_log is None:
                    t0_log = rec.log_time
                due = t0 + (rec.log_time - t0_log) / 1e9 / speed
                delay = due - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            pub = publishers.get(rec.key)
            if pub is None:
                pub = publishers[rec.key] = declare_publisher(session, rec.key, congestion="block")
            if signer is None:
                pub.put(rec.data)
            else:
                attachment = signer.sign(rec.key, rec.data)
                if attachment is None:  # nobody in particular publishes it (config, control): not re-published
                    continue
                pub.put(rec.data, attachment=attachment)
            counts[kind] = counts.get(kind, 0) + 1
            if on_record is not None:
                on_record(rec)
    for pub in publishers.values():
        pub.undeclare()
    return counts
