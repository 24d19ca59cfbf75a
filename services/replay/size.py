"""`python -m services.replay size LOG`: what a log costs, per 1,000 steps and per topic (payload bytes before
compression; the file is zstd-compressed). Reads any log, also those written before topics dropped the run id."""

from __future__ import annotations

import collections
import os
import warnings


def log_size(path) -> dict:
    from common.logs.mcap_log import LogRecoveryWarning, read_log, segment_paths
    from pathlib import Path

    p = Path(path)
    p = p / "session.mcap" if p.is_dir() else p
    files = segment_paths(p)
    per_topic: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogRecoveryWarning)
        for rec in read_log(p, decode=False):
            kind = "/" + rec.key.split("/", 2)[2] if rec.key.count("/") >= 2 else rec.key
            kind = "/" + kind.split("/")[1]  # by kind: all teachers' feedback together
            per_topic[kind][0] += 1
            per_topic[kind][1] += len(rec.data)
    total = sum(os.path.getsize(f) for f in files)
    steps = per_topic.get("/step", [0, 0])[0]
    return {
        "file_bytes": total,
        "steps": steps,
        "bytes_per_1000_steps": round(total * 1000 / steps) if steps else None,
        "topics": {k: {"messages": n, "payload_bytes": b} for k, (n, b) in sorted(per_topic.items())},
    }


def format_size(s: dict) -> str:
    lines = [
        f"file: {s['file_bytes']} bytes for {s['steps']} steps: {s['bytes_per_1000_steps']} bytes per 1,000 steps",
        f"  {'topic':<14} {'messages':>9} {'payload bytes':>14} {'per 1,000 steps':>16}",
    ]
    for k, v in s["topics"].items():
        per = round(v["payload_bytes"] * 1000 / s["steps"]) if s["steps"] else 0
        lines.append(f"  {k:<14} {v['messages']:>9} {v['payload_bytes']:>14} {per:>16}")
    return "\n".join(lines)
