"""`python -m services chaos`: kill every service with SIGKILL in turn during one live run, and compare it with
an undisturbed run of the same seed (docs/faults.md has the figures this printed here).

Both runs are `python -m services up` at a fixed actor rate for a fixed number of steps. During the chaos run,
once the learner has learned a step, each service in `kill` gets SIGKILL (`first_kill` s after that, then `gap` s
after the previous one came back); the launcher restarts it. At the end this reads both summaries and the log and
reports: steps and feedback lost (sent but never ingested by the learner, across its restarts), the time each
service took to come back (SIGKILL -> its liveliness token again) and what the learner did on restore,
inputs rejected by reason, how the log (all segments) reads back, whether `replay retrain` reproduces the
final weights from the whole record, and the final returns of both runs.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.agents import ALGOS
from common.config import option

ROOT = Path(__file__).resolve().parents[1]
SERVICES = ("recorder", "learner", "teacher.oracle", "actor")


@dataclass(frozen=True)
class ChaosConfig:
    """SIGKILL each service in turn during a live run; report losses, recovery times, rejected inputs, and the
    final return against an undisturbed run of the same seed."""

    out: str = option("runs/chaos", "directory of the two runs and chaos.json")
    seed: int = option(0, "trial seed of both runs")
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    rate: float = option(40.0, "actor steps per second (fixed, so the kills land in the middle of the run)")
    max_steps: int = option(1400, "steps per run")
    kill: tuple[str, ...] = option(SERVICES, "services to SIGKILL, in this order")
    first_kill: float = option(5.0, "seconds after the learner's first learned step before the first kill")
    gap: float = option(3.0, "seconds after a killed service is back before the next kill")
    baseline: bool = option(True, "also run the undisturbed run (for the return comparison)")
    alongside: bool = option(
        False,
        "run the undisturbed run at the same time as the chaos run, not before it (quicker; the two share the machine)",
    )
    timeout: float = option(240.0, "seconds each run may take")

    def __post_init__(self):
        bad = [k for k in self.kill if k not in SERVICES]
        if bad:
            raise ValueError(f"unknown services {bad}; choose from {', '.join(SERVICES)}")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def start_run(cfg: ChaosConfig, run: str, *extra: str) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "services",
        "up",
        "--out",
        cfg.out,
        "--run",
        run,
        "--progress",
        "false",
        "--seed",
        str(cfg.seed),
        "--algo",
        cfg.algo,
        "--rate",
        str(cfg.rate),
        "--max-steps",
        str(cfg.max_steps),
        "--episodes",
        "100000",
        *extra,
    ]
    return subprocess.Popen(
        cmd, cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )


def service_pids(rundir: Path, name: str) -> list[int]:
    """Live processes started with this run's config file of service `name`."""
    import psutil

    marker = str(rundir / "config" / f"{name}.json")
    out = []
    for p in psutil.process_iter(["pid", "cmdline", "status"]):
        try:
            if p.info["status"] != psutil.STATUS_ZOMBIE and marker in (p.info["cmdline"] or []):
                out.append(p.pid)
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
    return out


def wait_for(pred, timeout: float, period: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(period)
    return False


def alive_tokens(rundir: Path) -> Any:
    """A client of the run's router that records liveliness PUT times per service (to time recoveries) and
    records when steps and the learner's ingest records flow (under `"steps"` and `"ingest"`)."""
    import zenoh

    from common.protocol import ingest_key, step_key
    from common.wire.transport import client_config

    run_json = json.loads((rundir / "config" / "run.json").read_text())
    endpoint = run_json["launcher"]["endpoint"]
    run = run_json["launcher"]["run"]
    session = zenoh.open(client_config(endpoint))
    puts: dict[str, list[float]] = {}

    def on(sample):
        if sample.kind == zenoh.SampleKind.PUT:
            puts.setdefault(str(sample.key_expr).rsplit("/", 1)[-1], []).append(time.time())

    def on_step(sample):
        puts.setdefault("steps", []).append(time.time())

    def on_ingest(sample):
        puts.setdefault("ingest", []).append(time.time())

    try:
        sub = session.liveliness().declare_subscriber(f"hitl/{run}/alive/*", on, history=True)
        steps = session.declare_subscriber(step_key(run), on_step)
        ingest = session.declare_subscriber(ingest_key(run), on_ingest)
    except BaseException:
        session.close()
        raise
    return session, (sub, steps, ingest), puts


def kill_in_turn(cfg: ChaosConfig, rundir: Path, proc: subprocess.Popen) -> list[dict[str, Any]]:
    run_json = rundir / "config" / "run.json"
    if not wait_for(lambda: run_json.exists() or proc.poll() is not None, 90):
        raise RuntimeError("the run never started")
    session, subs, puts = alive_tokens(rundir)
    kills = []
    try:
        if not wait_for(lambda: len(puts.get("steps", ())) >= 1 or proc.poll() is not None, 120):
            raise RuntimeError("steps never started flowing")
        # The clock starts once the learner has learned a step: on a loaded machine the first steps can wait seconds
        # for it, and a learner killed before it learned anything leaves no record to restore (seen once).
        if not wait_for(lambda: len(puts.get("ingest", ())) >= 1 or proc.poll() is not None, 120):
            raise RuntimeError("the learner never learned a step")
        time.sleep(cfg.first_kill)
        for name in cfg.kill:
            if proc.poll() is not None:
                break
            pids = service_pids(rundir, name)
            if not pids:
                kills.append({"service": name, "skipped": "not running"})
                continue
            t_kill = time.time()
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
            back = wait_for(lambda name=name, t_kill=t_kill: any(t > t_kill for t in puts.get(name, [])), 60)
            t_back = min((t for t in puts.get(name, []) if t > t_kill), default=None)
            kills.append(
                {
                    "service": name,
                    "pid": pids[0],
                    "t_kill": t_kill,
                    "back_after_s": round(t_back - t_kill, 3) if back and t_back else None,
                }
            )
            time.sleep(cfg.gap)
    finally:
        for sub in subs:
            sub.undeclare()
        session.close()
    return kills


def _learner_events(rundir: Path) -> list[str]:
    from common.logs.mcap_log import read_log
    from common.protocol import Log

    out = []
    for rec in read_log(rundir / "session.mcap"):
        if isinstance(rec.message, Log):
            out.append(f"{rec.message.name}: {rec.message.message}")
    return out


def report(cfg: ChaosConfig, chaos_dir: Path, base_dir: Path | None, kills: list[dict]) -> dict[str, Any]:
    import numpy as np

    from common.logs.mcap_log import LogRecoveryWarning, read_log
    from services.replay.retrain import retrain

    s = json.loads((chaos_dir / "summary.json").read_text())
    b = json.loads((base_dir / "summary.json").read_text()) if base_dir else None

    def finished_returns(summary):
        return [e["return"] for e in summary["episodes"] if e["finished"]]

    with warnings.catch_warnings():  # the killed recorder's segment is cut: expected, reported below
        warnings.simplefilter("ignore", LogRecoveryWarning)
        reader = read_log(chaos_dir / "session.mcap")
        n = sum(1 for _ in reader)
        learner_restart = [
            e
            for e in _learner_events(chaos_dir)
            if e.startswith("learner: restored") or e.startswith("learner: started without")
        ]
        rt = retrain(chaos_dir / "session.mcap")
    k = 10
    out = {
        "outcome": s["outcome"],
        "kills": kills,
        "restarts": s.get("restarts", []),
        "learner_restore": learner_restart,
        "steps": {
            "sent": s["steps_sent"],
            "logged": s["steps_logged"],
            "learned": s["steps_learned"],
            "lost_sent_not_ingested": (s["steps_sent"] or 0) - (s["steps_logged"] or 0) + s["steps_not_ingested"],
            "not_logged": (s["steps_sent"] or 0) - s["steps_logged"],
            "logged_not_ingested": s["steps_not_ingested"],
            "learner_step_entries": s["learner_step_entries"],
            "learner_seq_contiguous": s["learner_seq_contiguous"],
            "actor_incarnations": s["actor_incarnations"],
        },
        "feedback": {
            "sent": s["feedback_sent"],
            "logged": s["feedback_logged"],
            "not_logged": (s["feedback_sent"] or 0) - s["feedback_logged"],
            "logged_not_ingested": s["feedback_not_ingested"],
            "credited": s["feedback_credited"],
            "rejected": s["feedback_rejected"],
        },
        "rejected_inputs": s["rejected_inputs"],
        "duplicates_dropped": s["duplicates_dropped"],
        "log": {
            "segments": len(reader.status.files),
            "messages": n,
            "truncated": reader.status.truncated,
            "steps_contiguous_per_incarnation": s["steps_seq_contiguous_in_log"],
            "duplicates_skipped": dict(reader.status.duplicates_skipped),
        },
        "retrain": {
            "learners": s["learner_chain"],
            "identical": rt.identical,
            "compared": rt.compared,
            "outcomes_match": rt.outcomes_match,
            "mismatch": rt.entry_mismatch,
        },
        "returns": {
            "chaos_last10_mean": float(np.mean(finished_returns(s)[-k:])),
            "chaos_episodes": len(finished_returns(s)),
        },
    }
    if b is not None:
        out["returns"].update(
            baseline_last10_mean=float(np.mean(finished_returns(b)[-k:])),
            baseline_episodes=len(finished_returns(b)),
            baseline_range_last10=[float(min(finished_returns(b)[-k:])), float(max(finished_returns(b)[-k:]))],
        )
    return out


def format_report(r: dict[str, Any]) -> str:
    lines = [f"chaos run: {r['outcome']}"]
    rest = {x["service"]: x for x in r["restarts"]}
    for kx in r["kills"]:
        if "skipped" in kx:
            lines.append(f"  {kx['service']:15s} not killed ({kx['skipped']})")
            continue
        lines.append(
            f"  {kx['service']:15s} SIGKILL -> ready again after {kx['back_after_s']} s "
            f"(launcher: {rest.get(kx['service'], {}).get('how', '?')})"
        )
    for e in r["learner_restore"]:
        lines.append(f"  {e}")
    st, fb = r["steps"], r["feedback"]
    lines.append(
        f"  steps: sent {st['sent']}, logged {st['logged']}, learned {st['learned']}; lost (sent, never "
        f"ingested) {st['lost_sent_not_ingested']}; learner entries {st['learner_step_entries']}, seqs "
        f"contiguous {st['learner_seq_contiguous']}, actor incarnations {st['actor_incarnations']}"
    )
    lines.append(
        f"  feedback: sent {fb['sent']}, logged {fb['logged']} (not logged {fb['not_logged']}), logged "
        f"but not ingested {fb['logged_not_ingested']}, credited {fb['credited']}, rejected {fb['rejected']}"
    )
    lines.append(f"  rejected inputs: {r['rejected_inputs'] or 'none'}; duplicates dropped: {r['duplicates_dropped']}")
    lg = r["log"]
    lines.append(
        f"  log: {lg['segments']} segments, {lg['messages']} messages, truncated {len(lg['truncated'])} "
        f"(recovered), duplicates skipped {lg['duplicates_skipped']}, steps contiguous "
        f"{lg['steps_contiguous_per_incarnation']}"
    )
    rt = r["retrain"]
    lines.append(
        f"  retrain over learners {len(rt['learners'])}: outcomes match {rt['outcomes_match']}, final weights "
        f"{'IDENTICAL' if rt['identical'] else 'different' if rt['compared'] else 'not compared'}"
    )
    ret = r["returns"]
    lines.append(
        f"  returns: chaos last-10 mean {ret['chaos_last10_mean']:.3f} ({ret['chaos_episodes']} episodes)"
        + (
            f"; undisturbed {ret['baseline_last10_mean']:.3f} ({ret['baseline_episodes']} episodes, last-10 "
            f"range {ret['baseline_range_last10']})"
            if "baseline_last10_mean" in ret
            else ""
        )
    )
    return "\n".join(lines)


def _finished(base: subprocess.Popen, timeout: float) -> bool:
    """The undisturbed run ended well (else its output is printed)."""
    try:
        text, _ = base.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(base.pid, signal.SIGKILL)
        raise
    if base.returncode != 0:
        print(text, file=sys.stderr)
    return base.returncode == 0


def chaos(cfg: ChaosConfig) -> int:
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%H%M%S")
    base = start_run(cfg, f"calm-{stamp}") if cfg.baseline else None
    if base is not None and not cfg.alongside and not _finished(base, cfg.timeout):
        return 1
    run = f"chaos-{stamp}"
    proc = start_run(cfg, run)
    try:
        kills = kill_in_turn(cfg, out / run, proc)
        text, _ = proc.communicate(timeout=cfg.timeout)
        if base is not None and cfg.alongside and not _finished(base, cfg.timeout):
            return 1
    except BaseException:
        for p in (proc, base):
            if p is not None and p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
        raise
    base_dir = out / f"calm-{stamp}" if base is not None else None
    r = report(cfg, out / run, base_dir, kills)
    r["launcher_exit"] = proc.returncode
    (out / f"{run}.json").write_text(json.dumps(r, indent=2))
    print(format_report(r))
    print(f"(details: {out / run}.json; the run's own output: {out / run}/launcher.out)", file=sys.stderr)
    (out / run / "launcher.out").write_text(text)
    return 0 if proc.returncode == 0 else 1
