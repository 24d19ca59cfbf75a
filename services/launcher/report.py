"""What the user sees: the progress bar (fed by authenticated EpisodeSummary messages) and the run's summary."""

from __future__ import annotations

import json
import sys
from typing import Any

from services.launcher.children import Child
from services.launcher.config import UpConfig
from services.launcher.rundir import RunDir, is_disk_full


class Progress:
    """Progress bar fed by EpisodeSummary messages (received on the router's own session through an inbox
    that checks their authentication; never blocking: it is the router's thread)."""

    def __init__(self, total: int, enabled: bool, label: str):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=label, unit="ep", file=sys.stderr, disable=not enabled, dynamic_ncols=True)
        self.received = self.credited = 0
        self.count = 0
        self.seen: set[tuple[str, int]] = set()
        self.inbox: Any = None

    def subscribe(self, session: Any, run: str) -> Any:
        from common.protocol import episode_key
        from common.wire.transport import subscribe

        sub, self.inbox = subscribe(session, episode_key(run), maxsize=4096, policy="drop_oldest")
        return sub

    def pump(self) -> None:
        while self.inbox is not None and (got := self.inbox.get_message(timeout=0)) is not None:
            ep = got[1]
            if (ep.incarnation, ep.episode) in self.seen:  # re-sent by a restored learner
                continue
            self.seen.add((ep.incarnation, ep.episode))
            self.count += 1
            self.received += ep.feedback_received
            self.credited += ep.feedback_credited
            self.bar.update(1)
            self.bar.set_postfix_str(
                f"ep {ep.episode} return {ep.return_:.2f} steps {ep.steps} "
                f"feedback {self.received} recv/{self.credited} credited "
                f"weights v{ep.weights_version}"
            )

    def close(self) -> None:
        self.pump()
        self.bar.close()


EXIT_CODES = {"ok": 0, "interrupted": 130}


def finish(
    cfg: UpConfig,
    run: str,
    rundir: RunDir,
    endpoint: str,
    children: list[Child],
    outcome: str,
    wall: float,
    restarts: list[dict] | None = None,
    everyone: list[Child] | None = None,
    error: str | None = None,
) -> int:
    """Summarize the log into summary.json (and the learning curve); whatever the disk allows."""
    from services.replay.summary import format_summary

    summary: dict[str, Any] = {
        "run": run,
        "outcome": outcome,
        "endpoint": endpoint,
        "wall_s": round(wall, 3),
        "exit_codes": {c.name: c.popen.returncode for c in children},
        "restarts": restarts or [],
        "exit_history": [
            {"service": c.name, "pid": c.popen.pid, "exit": c.popen.returncode} for c in (everyone or children)
        ],
    }
    if error:
        summary["error"] = error
    title = f"{cfg.algo} on {cfg.env} (live, teacher {cfg.teacher}, seed {cfg.seed})"
    drawn = write_summary_from_log(summary, rundir, title, cfg.curve)
    figure = ", learning_curve.png" if drawn else ""
    if "returns" in summary:
        print(format_summary(summary), file=sys.stderr)
    if error:
        print(f"error: {error}", file=sys.stderr)
    print(f"wrote {rundir.path}/session.mcap, summary.json{figure} ({outcome}, {wall:.1f} s)", file=sys.stderr)
    return EXIT_CODES.get(outcome, 1)


def write_summary_from_log(summary: dict[str, Any], rundir: RunDir, title: str, curve: bool = True) -> bool:
    """Add the log's counts to `summary` (its outcome and restarts stay), plot the learning curve, add the
    latencies, and write summary.json: whatever the disk allows (the counts fit the space reserved for it).
    Whether learning_curve.png was drawn (not without matplotlib, the `experiments` extra)."""
    from services.replay.curve import plot_summary
    from services.replay.summary import summarize

    log = rundir.path / "session.mcap"
    keep: dict[str, Any] = {k: summary[k] for k in ("outcome", "restarts") if k in summary}
    if log.exists() and log.stat().st_size:
        try:
            summary.update(summarize(log))
            summary.update(keep)
        except Exception as exc:  # a damaged log still gets a summary.json saying so
            summary["summary_error"] = f"{type(exc).__name__}: {exc}"
    drawn = False
    if "returns" in summary and curve:
        try:
            drawn = plot_summary(summary, rundir.path / "learning_curve.png", title)
        except Exception as exc:  # a full disk: no plot (and no 0-byte file), the counts still go out
            summary["plot_error"] = f"{type(exc).__name__}: {exc}"
    stats = read_stats(rundir)
    summary["latency_ms"] = latency_table(stats)
    # Each teacher's delay as the learner credited it at the end (learned in seconds, or what it assumed).
    summary["delay"] = stats.get("learner", {}).get("delay", {})
    try:
        rundir.write_summary(summary)
    except OSError as exc:
        print(f"error: could not write {rundir.path}/summary.json: {exc.strerror or exc}", file=sys.stderr)
    return drawn


def read_stats(rundir: RunDir) -> dict[str, dict]:
    stats = {}
    for p in sorted((rundir.path / "stats").glob("*.json")):
        try:
            stats[p.stem] = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            if is_disk_full(exc):
                break
    return stats


def percentiles(values: list[float]) -> dict[str, float] | None:
    import numpy as np

    if not values:
        return None
    a = np.asarray(values, dtype=float) * 1e3
    return {
        "n": int(a.size),
        "p50": round(float(np.percentile(a, 50)), 3),
        "p99": round(float(np.percentile(a, 99)), 3),
        "max": round(float(a.max()), 3),
    }


def latency_table(stats: dict[str, dict]) -> dict[str, Any]:
    out = {}
    learner = stats.get("learner", {}).get("samples", {})
    actor = stats.get("actor", {}).get("samples", {})
    out["feedback_to_h_update"] = percentiles(learner.get("feedback_to_h_s", []))
    out["weights_publish_to_adoption"] = percentiles(actor.get("adopt_latency_s", []))
    return out
