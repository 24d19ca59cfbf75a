"""REPORT.md's parts that depend on the declaration a run decided under (experiments/declarations.py): the method
of the declaration of 28 November, and the settlement table of its two runs (issue 34 item 4: a claim settles only
where two runs of the same design agree).

    python -m experiments settle RUN1/claims.json RUN2/claims.json --out SETTLEMENT.md
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

from common.config import option
from experiments.claims import ALPHA, MARGIN, RETURN_MARGIN
from experiments.declarations import Declaration, of_run


def settlement(run_1: dict, run_2: dict) -> list[dict]:
    """Side by side, per claim of either run (claims.json's content): run 1's and run 2's verdicts, and whether the
    claim settled (both runs evaluated it and gave the same verdict). Both runs must be of one declaration."""
    d1, d2 = of_run(run_1), of_run(run_2)
    if d1.id != d2.id:
        raise ValueError(f"the runs decided under different declarations ({d1.id}, {d2.id}): nothing settles")
    c1, c2 = run_1["claims"], run_2["claims"]
    rows = []
    for cid in list(c1) + [k for k in c2 if k not in c1]:
        v1, v2 = (c.get(cid, {}).get("verdict", "not evaluated") for c in (c1, c2))
        rows.append(
            {
                "claim": cid,
                "run_1": v1,
                "run_2": v2,
                "settled": v1 == v2 and v1 != "not evaluated",
                "expected_unsettled": cid in d1.expected_unsettled,
            }
        )
    return rows


def settlement_lines(rows: list[dict]) -> list[str]:
    """The settlement table as REPORT.md shows it."""
    lines = [
        "## Settled: where the two runs agree",
        "",
        "A claim settles only where two runs of the same declared design, on fresh layouts and seeds each, give the "
        "same verdict (issue 34 item 4); its settled verdict is that one.",
        "",
        "| claim | run 1 verdict | run 2 verdict | settled |",
        "|---|---|---|---|",
    ]
    for r in rows:
        mark = " (expected unsettled, declared before the runs)" if r["expected_unsettled"] else ""
        lines.append(
            f"| {r['claim']}{mark} | {r['run_1']} | {r['run_2']} | {'yes: ' + r['run_1'] if r['settled'] else 'no'} |"
        )
    return lines + [""]


def settlement_against(result: dict, other_path: str, replicate: int | None) -> list[dict]:
    """This run (claims.json's content) against the other run's claims.json; this run is run 2 where its replicate
    is 2, else run 1."""
    with open(other_path) as fh:
        other = json.load(fh)
    return settlement(other, result) if replicate == 2 else settlement(result, other)


def write_settlement(path_1: str, path_2: str, out: str) -> list[dict]:
    """The two runs' claims.json side by side, written to `out` (Markdown)."""
    with open(path_1) as f1, open(path_2) as f2:
        rows = settlement(json.load(f1), json.load(f2))
    with open(out, "w") as fh:
        fh.write("\n".join(settlement_lines(rows)))
    return rows


@dataclass(frozen=True)
class SettleConfig:
    """Two runs of one declared design side by side: each claim's verdict in each, and whether it settled."""

    run_1: str = option("", "run 1's claims.json", positional=True)
    run_2: str = option("", "run 2's claims.json", positional=True)
    out: str = option("settlement.md", "where the table is written (Markdown)")


def settle_main(args: SettleConfig) -> int:
    try:
        rows = write_settlement(args.run_1, args.run_2, args.out)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {sum(r['settled'] for r in rows)} of {len(rows)} claims settled")
    return 0


def method_lines(decl: Declaration, ev: dict) -> list[str]:
    """The method of a declaration where ln steps alone decides (28 November on)."""
    unsettled = ", ".join(decl.expected_unsettled) or "none"
    return [
        f"## Method (the declaration of {decl.id}, `{decl.module}`, committed before its runs)",
        "",
        f"- One primary metric, per trial over the test's episode window: the mean of ln(steps per episode) (lower is "
        f"better; margin ln 1.1 = {MARGIN:.3f}, 10% fewer steps). The mean return per episode (margin "
        f"{RETURN_MARGIN['maze']} on the Maze, {RETURN_MARGIN['taxi']} on Taxi) is computed and shown with its own "
        "Holm p, and never decides.",
        f"- **reproduced** when the Holm-adjusted p < {ALPHA} (Holm across the family's primary tests); **not "
        "reproduced** when some component's 95% interval lies wholly below its margin (non-inferiority: below minus "
        "the margin); **inconclusive** otherwise.",
        "- Population: the paper's claims C1-C6 on every maze layout pooled (Taxi: all its trials); D1-D3 on the "
        "learned-delay conditions' honest layouts; A1 and M1 on the misleading layouts. The honest-only and "
        "misleading-only results and the layout-class x method interaction (honest minus misleading, two-sided "
        "Welch t-test over the layouts' means) are a declared secondary: shown, never deciding.",
        "- Resampling unit: the maze layout is the cluster (its seeds averaged within it); Gymnasium's Taxi: the "
        f"seed. Estimate: mean over trials; interval: 95% percentile bootstrap resampling whole clusters "
        f"({ev['n_boot']} resamples); p: one-sided t-test over the clusters' means. A test of several effects that "
        "must all hold shows its weakest component (the largest p).",
        "- Robustness of the decision (never deciding): Wilcoxon signed-rank instead of t, the per-trial median of ln "
        "steps, each with the same Holm factor; **fragile** where either flips it. MDE: the smallest true effect the "
        "design detects with 80% power at level alpha/m.",
        f"- Expected unsettled, declared before the runs from the power analysis "
        f"(docs/notes/2026-11-28-power.md): {unsettled}. Their effects in the earlier run lay between 0 and the "
        "margin, where two runs of any affordable size often disagree; their verdicts are reported as they fall.",
        "",
    ]
