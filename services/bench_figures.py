"""`python -m services.bench_figures NEW_OUT[,NEW_OUT...] OLD_OUT[,OLD_OUT...]`: the figures of `services bench` runs
of two checkouts side by side, read from their run directories (so both are read alike, whatever the checkout's own
bench printed), with the ratio new / old of the means.

Besides the bench's own figures it gives the latencies with start-up left out (the steps acted, and the feedback
sent, in the first `STARTUP_S` s of a phase), next to the whole run's: the start-up is reported, not hidden.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

import numpy as np

STARTUP_S = 5.0
PHASES = ("paper", "rate")


def latencies(rundir: Path) -> dict[str, float]:
    """p50/p99 (ms) of step -> learned and feedback -> credited, whole run and after start-up."""
    from common.logs.mcap_log import read_log
    from common.protocol import Credit, Feedback, Ingest, Step

    t_action, learned, sent, credited = [], [], {}, {}
    for rec in read_log(rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Step):
            t_action.append(m.t_action)
        elif isinstance(m, Ingest):
            learned += [e.t for e in m.entries if e.kind == "step"]
        elif isinstance(m, Feedback):
            sent[(m.teacher_id, m.seq)] = rec.publish_time / 1e9
        elif isinstance(m, Credit) and m.status == "credited":
            credited[(m.teacher_id, m.seq)] = m.t_credited
    n = min(len(t_action), len(learned))
    acted, lag = np.asarray(t_action[:n]), 1e3 * (np.asarray(learned[:n]) - np.asarray(t_action[:n]))
    keys = [k for k in credited if k in sent]
    fb_t = np.asarray([sent[k] for k in keys])
    fb_lag = 1e3 * (np.asarray([credited[k] for k in keys]) - fb_t)
    t0 = acted[0] if n else 0.0
    out = {}
    for name, t, v in (("step_learned", acted, lag), ("feedback_credited", fb_t, fb_lag)):
        for part, keep in (("all", np.ones(len(v), bool)), ("after_start", t >= t0 + STARTUP_S)):
            for q in (50, 99):
                out[f"{name}_{part}_p{q}"] = float(np.percentile(v[keep], q)) if keep.any() else float("nan")
    return out


def figures(out_dirs: list[Path]) -> dict[str, list[dict[str, float]]]:
    """Per phase, one dict of figures per bench run found under the given --out directories."""
    found: dict[str, list[dict[str, float]]] = {p: [] for p in PHASES}
    for out in out_dirs:
        for path in sorted(out.glob("bench-*.json")):
            for phase, r in json.loads(path.read_text())["phases"].items():
                if phase not in found:
                    continue
                rundir = out / f"{path.stem}-{phase}"
                cpu = r["cpu_ms_per_step"]
                row = {"steps_per_s": r["steps_per_s"] or float("nan"), "zero_loss": float(r["zero_loss"])}
                row.update({f"cpu_{k}": v for k, v in cpu.items()})
                row["cpu_total"] = sum(cpu.values())
                row.update(latencies(rundir))
                found[phase].append(row)
    return found


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.split("\n\n")[0], file=sys.stderr)
        return 2
    new, old = (figures([Path(p) for p in arg.split(",")]) for arg in argv)
    for phase in PHASES:
        if not new[phase] or not old[phase]:
            continue
        runs = f"new {len(new[phase])} runs, old {len(old[phase])} runs"
        print(f"\n{phase}: {runs} (means; each run's value in brackets)")
        for key in new[phase][0]:
            a = [r.get(key, float("nan")) for r in new[phase]]
            b = [r.get(key, float("nan")) for r in old[phase]]
            ma, mb = statistics.fmean(a), statistics.fmean(b)
            each = f"[{', '.join(f'{x:.2f}' for x in a)}] vs [{', '.join(f'{x:.2f}' for x in b)}]"
            print(f"  {key:32s} {ma:9.2f} {mb:9.2f}  ratio {ma / mb if mb else float('nan'):6.2f}  {each}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
