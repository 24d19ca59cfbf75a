"""`python -m services bench`: figures of the live system on this machine (a benchmark, not a test).

Each phase is a real run of `python -m services up` (embedded router, every service its own process,
recorder on) for a fixed number of steps; the figures come from its log, its summary and the services'
stats files. During each phase a ping/pong pair (this process and an echo process, both clients of the same
router) measures the raw Zenoh round trip for scale, on keys outside `hitl/` so nothing else sees them.

Phases (default: all):
  ingest      DQN with no gradient updates (update-interval 10^9), as fast as possible: transport, the
              learner's ingest, recording - what the plumbing sustains without training
  paper       the main job's agent at the paper's settings (b = 1), as fast as possible, actor at most
              `max_ahead` steps ahead of its weights: sustained steps/s of the whole system with learning
  paper-b4    the same with a minibatch update every 4 steps (b = 4; Algorithm 2's knob)
  rate        a fixed actor rate (`rate`), b = 1, actor never waiting for weights: latencies at that load
  paced       a person's pace (`paced-rate`, 2 steps/s) taught by a scripted page in Debian's Chromium: each
              service's and the browser's share of one core, read from /proc after start-up
              (services/bench_paced.py); with `paced-checkouts` the same on other checkouts, side by side

Zero loss is checked in every phase: the actor's count, the log's Step seqs and the learner's ingest agree.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.agents import ALGOS
from common.config import option
from common.core.task import Task

PHASES = ("ingest", "paper", "paper-b4", "rate", "paced")
PING_KEY = "hitl-bench/{run}/ping"
PONG_KEY = "hitl-bench/{run}/pong"


@dataclass(frozen=True)
class BenchConfig:
    """Throughput (steps/s with zero loss) and latencies (feedback -> H update, weights -> actor) of the live
    system on this machine, with the raw Zenoh round trip for scale."""

    env: str = option("maze", "environment (a project name, Gymnasium id or module:factory)")
    algo: str = option("dqn-tamer", "agent of the learning phases", choices=ALGOS)
    steps: int = option(8000, "actor steps per phase")
    rate: float = option(250.0, "actor steps per second in the 'rate' phase (one the learner keeps up with)")
    max_ahead: int = option(8, "steps the actor may run ahead of its weights in the as-fast-as-possible phases")
    phases: tuple[str, ...] = option(PHASES, f"phases to run, comma-separated, of {', '.join(PHASES)}")
    out: str = option("runs/bench", "directory of the phases' run directories and bench.json")
    ping_period: float = option(0.005, "seconds between Zenoh pings")
    paced_seconds: float = option(60.0, "paced phase: seconds measured (after paced-warmup)")
    paced_warmup: float = option(15.0, "paced phase: seconds of start-up left out once the page is in")
    paced_rate: float = option(2.0, "paced phase: actor steps per second (a person's pace)")
    paced_checkouts: tuple[str, ...] = option(
        (),
        "paced phase: other checkouts of the project to measure the "
        "same way after this one (e.g. the base commit's), comma-separated",
    )

    def __post_init__(self):
        Task(env=self.env)  # a bad env is a one-line error here
        bad = [p for p in self.phases if p not in PHASES]
        if bad:
            raise ValueError(f"unknown phases {bad}; choose from {', '.join(PHASES)}")
        if self.steps < 100:
            raise ValueError(f"steps must be >= 100, got {self.steps}")


def pct(values, scale: float = 1e3) -> dict[str, float] | None:
    if values is None or len(values) == 0:
        return None
    a = np.asarray(values, float) * scale
    return {
        "n": int(a.size),
        "p50": round(float(np.percentile(a, 50)), 3),
        "p99": round(float(np.percentile(a, 99)), 3),
        "max": round(float(a.max()), 3),
    }


class Pinger:
    """Raw Zenoh round trips through the run's router: this process pings, an echo process answers. The router's
    endpoint is read from the run record once the launcher has written it (the launcher picks the port at its bind)."""

    def __init__(self, rundir: Path, run: str, period: float):
        self.rundir, self.run, self.period = rundir, run, period
        self.samples: list[tuple[float, float]] = []  # (wall time sent, rtt s)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="pinger", daemon=True)
        self.echo: subprocess.Popen | None = None
        self.error: str | None = None

    def start(self) -> None:
        self.thread.start()

    def _loop(self) -> None:
        import queue

        import zenoh

        from common.wire.transport import client_config, open_session, wait_for_matching

        try:
            from services.launcher.rundir import recorded_router

            endpoint = recorded_router(self.rundir, self.stop.is_set)
            if endpoint is None:
                return
            with open_session(client_config(endpoint, connect_timeout=60)) as session:
                from services.launcher import ROOT, child_env

                self.echo = subprocess.Popen(
                    [sys.executable, "-c", ECHO, endpoint, self.run],
                    cwd=str(ROOT),
                    env=child_env(),
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
                q: queue.Queue = queue.Queue()
                sub = session.declare_subscriber(PONG_KEY.format(run=self.run), lambda s: q.put(time.perf_counter()))
                pub = session.declare_publisher(
                    PING_KEY.format(run=self.run), express=True, congestion_control=zenoh.CongestionControl.BLOCK
                )
                wait_for_matching(pub, 60)
                payload = bytes(64)
                while not self.stop.is_set():
                    t_wall, t0 = time.time(), time.perf_counter()
                    pub.put(payload)
                    try:
                        t1 = q.get(timeout=1.0)
                        self.samples.append((t_wall, t1 - t0))
                    except queue.Empty:
                        pass
                    self.stop.wait(self.period)
                sub.undeclare()
                pub.undeclare()
        except Exception as exc:  # the figure is then missing, the bench goes on
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            if self.echo is not None:
                self.echo.terminate()
                try:
                    self.echo.wait(5)
                except subprocess.TimeoutExpired:
                    self.echo.kill()

    def finish(self) -> None:
        self.stop.set()
        self.thread.join(15)


# The echo side runs in its own process (a child, not a command of its own).
ECHO = "import sys; from services.bench import echo_main; sys.exit(echo_main(sys.argv[1], sys.argv[2]))"


def echo_main(endpoint: str, run: str) -> int:
    """The echo side: answer every ping on the pong key (runs until terminated)."""
    import signal

    import zenoh

    from common.wire.transport import client_config, open_session

    from services.common.runtime import set_from_handler

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: set_from_handler(stop))
    with open_session(client_config(endpoint, connect_timeout=30)) as session:
        pub = session.declare_publisher(
            PONG_KEY.format(run=run), express=True, congestion_control=zenoh.CongestionControl.BLOCK
        )
        sub = session.declare_subscriber(PING_KEY.format(run=run), lambda s: pub.put(s.payload))
        while not stop.wait(0.2):
            pass
        sub.undeclare()
        pub.undeclare()
    return 0


def phase_settings(name: str, cfg: BenchConfig) -> dict[str, Any]:
    base = dict(task=Task(env=cfg.env), algo=cfg.algo, episodes=10**9, max_steps=cfg.steps, progress=False)
    if name == "ingest":
        return {**base, "algo": "dqn", "update_interval": 10**9, "max_ahead": cfg.max_ahead}
    if name == "paper":
        return {**base, "max_ahead": cfg.max_ahead}
    if name == "paper-b4":
        return {**base, "max_ahead": cfg.max_ahead, "update_interval": 4}
    return {**base, "rate": cfg.rate, "max_ahead": None}


def analyse(rundir: Path) -> dict[str, Any]:
    from common.logs.mcap_log import read_log
    from common.protocol import Ingest, Step

    summary = json.loads((rundir / "summary.json").read_text())
    t_action, learned_t = [], []
    for rec in read_log(rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Step):
            t_action.append(m.t_action)
        elif isinstance(m, Ingest):
            learned_t += [e.t for e in m.entries if e.kind == "step"]
    stats = {}
    for p in (rundir / "stats").glob("*.json"):
        stats[p.stem] = json.loads(p.read_text())
    n = summary.get("steps_sent") or 0
    zero_loss = (
        summary.get("steps_logged") == n
        and summary.get("steps_learned") == n
        and summary.get("steps_seq_contiguous_in_log")
        and summary.get("learner_step_entries") == {"learned": n}
        and summary.get("feedback_logged") == summary.get("feedback_sent")
        and "unresolved" not in summary.get("feedback_rejected", {})
    )
    span = (max(learned_t) - min(t_action)) if t_action and learned_t else float("nan")
    actor_span = (t_action[-1] - t_action[0]) if len(t_action) > 1 else float("nan")
    lag = (np.asarray(learned_t[: len(t_action)]) - np.asarray(t_action[: len(learned_t)])) if learned_t else []
    learner = stats.get("learner", {}).get("samples", {})
    actor = stats.get("actor", {}).get("samples", {})
    return {
        "steps": n,
        "zero_loss": bool(zero_loss),
        "outcome": summary.get("outcome"),
        "steps_per_s": round(n / span, 1) if span == span and span > 0 else None,
        "actor_steps_per_s": round(n / actor_span, 1) if actor_span == actor_span and actor_span > 0 else None,
        "step_to_learned_ms": pct(lag),
        "feedback_to_h_update_ms": pct(learner.get("feedback_to_h_s")),
        "feedback_to_h_update_after_hold_ms": pct(
            np.asarray(learner.get("feedback_to_h_s", [])) - np.asarray(learner.get("feedback_hold_s", []))
        ),
        "weights_publish_to_adoption_ms": pct(actor.get("adopt_latency_s")),
        "weights_publish_cost_ms": pct(learner.get("weights_publish_cost_s")),
        "cpu_ms_per_step": {
            name: round(1e3 * st.get("cpu_since_ready_s", 0.0) / max(n, 1), 3) for name, st in sorted(stats.items())
        },
        "feedback": {
            "sent": summary.get("feedback_sent"),
            "credited": summary.get("feedback_credited"),
            "rejected": summary.get("feedback_rejected"),
        },
        "t_first_step": t_action[0] if t_action else None,
        "t_last_step": t_action[-1] if t_action else None,
    }


def bench(cfg: BenchConfig) -> int:
    from services.launcher import UpConfig, up

    out = Path(cfg.out)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    results: dict[str, Any] = {
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "load_avg_before": [round(x, 2) for x in os.getloadavg()],
        },
        "config": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
        "phases": {},
    }
    for name in cfg.phases:
        if name == "paced":
            results["paced"] = run_paced(cfg, out, stamp)
            continue
        run = f"bench-{stamp}-{name}"
        pinger = Pinger(out / run, run, cfg.ping_period)
        pinger.start()
        print(f"\n== phase {name} ({cfg.steps} steps) ==", file=sys.stderr, flush=True)
        up_cfg = UpConfig.flat(out=str(out), run=run, **phase_settings(name, cfg))
        rc = up(up_cfg)
        pinger.finish()
        res = analyse(out / run)
        res["exit_code"] = rc
        t0, t1 = res.pop("t_first_step"), res.pop("t_last_step")
        rtts = pinger.samples
        res["zenoh_rtt_64B_ms"] = {
            "idle": pct([r for t, r in rtts if t0 is not None and t < t0]),
            "during_run": pct([r for t, r in rtts if t0 is not None and t0 <= t <= t1]),
        }
        if pinger.error:
            res["zenoh_rtt_error"] = pinger.error
        results["phases"][name] = res
        print(format_phase(name, res), file=sys.stderr, flush=True)
    results["machine"]["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"bench-{stamp}.json"
    path.write_text(json.dumps(results, indent=2))
    print("\n" + report(results), flush=True)
    print(f"\nwrote {path}", file=sys.stderr)
    paced = results.get("paced", {})
    ok = all(p["zero_loss"] and p["exit_code"] == 0 for p in [*results["phases"].values(), *paced.values()])
    return 0 if ok else 1


def run_paced(cfg: BenchConfig, out: Path, stamp: str) -> dict[str, Any]:
    from services.bench_paced import PacedSettings, format_paced, paced_phase

    print(f"\n== phase paced ({cfg.paced_rate:g} steps/s, {cfg.paced_seconds:g} s) ==", file=sys.stderr, flush=True)
    settings = PacedSettings(
        seconds=cfg.paced_seconds,
        warmup=cfg.paced_warmup,
        rate=cfg.paced_rate,
        env=cfg.env,
        algo=cfg.algo,
        out=out.resolve(),
    )
    res = paced_phase(settings, cfg.paced_checkouts, stamp)
    print(format_paced(res), file=sys.stderr, flush=True)
    return res


def _fmt(p: dict | None) -> str:
    return "n/a" if not p else f"p50 {p['p50']:.2f} / p99 {p['p99']:.2f} ms (n={p['n']})"


def format_phase(name: str, r: dict) -> str:
    rtt = r["zenoh_rtt_64B_ms"]
    return "\n".join(
        [
            f"{name}: {r['steps']} steps, zero loss: {'yes' if r['zero_loss'] else 'NO'}, "
            f"sustained {r['steps_per_s']} steps/s (actor {r['actor_steps_per_s']} steps/s)",
            f"  step -> learned            {_fmt(r['step_to_learned_ms'])}",
            f"  feedback -> H update       {_fmt(r['feedback_to_h_update_ms'])}",
            f"    less the wait for a newer step {_fmt(r['feedback_to_h_update_after_hold_ms'])}",
            f"  weights -> actor adoption  {_fmt(r['weights_publish_to_adoption_ms'])}",
            f"  zenoh RTT 64 B             idle {_fmt(rtt['idle'])}; during run {_fmt(rtt['during_run'])}",
            "  CPU ms per step (after start-up): " + ", ".join(f"{k} {v:.2f}" for k, v in r["cpu_ms_per_step"].items()),
        ]
    )


def report(results: dict) -> str:
    m = results["machine"]
    lines = [
        f"bench on {m['cpus']} CPUs, {m['platform']}, load average before {m['load_avg_before']} "
        f"after {m['load_avg_after']}"
    ]
    for name, r in results["phases"].items():
        lines.append(format_phase(name, r))
    if results.get("paced"):
        from services.bench_paced import format_paced

        lines.append(format_paced(results["paced"]))
    return "\n".join(lines)
