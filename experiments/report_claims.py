"""REPORT.md's claim sections: the verdict tables, the method, and per claim both co-primary metrics on
the primary population, the other layout classes, the layout-class x method interaction, robustness and
the secondary tests (all computed by experiments/evaluate.py)."""

from __future__ import annotations

from experiments.claims import ALPHA, MARGIN, METRICS, RETURN_MARGIN
from experiments.stats import fmt_p


def iv(r: dict | None, d: int = 3) -> str:
    if not r:
        return "n/a"
    return f"{r['estimate']:+.{d}f} [{r['ci'][0]:+.{d}f}, {r['ci'][1]:+.{d}f}]"


UNSETTLED = " (expected unsettled, declared before the runs)"


def verdict_text(c: dict) -> str:
    """The claim's verdict, and where the metrics differ, each metric's."""
    text = (
        f"**{c['verdict']}**"
        + (" (fragile)" if c.get("fragile") else "")
        + (UNSETTLED if c.get("expected_unsettled") else "")
    )
    if c["verdict"] == "mixed":
        text += " (" + "; ".join(f"{m}: {r['verdict']}" for m, r in c["metrics"].items()) + ")"
    return text


def verdict_table(claims: dict, family: str, previous: dict, deciding: tuple[str, ...] = METRICS) -> list[str]:
    shown = " (shown, never decides)" if "return" not in deciding else ""
    lines = [
        "| claim | verdict | previous | primary test | ln steps: estimate [95% CI], Holm p | "
        f"return{shown}: estimate [95% CI], Holm p | statement |",
        "|---|---|---|---|---|---|---|",
    ]
    for cid, c in claims.items():
        if c["family"] != family:
            continue
        test = (
            f"{c['primary_test']} ({c['layouts']} layouts"
            f"{', ' + c['window'] + ' episodes' if c['window'] != 'all' else ''})"
        )
        if c["verdict"] == "not evaluated":
            lines.append(f"| {cid} | not evaluated | {previous.get(cid, '-')} | {test} | | | {c['text']} |")
            continue
        cells = [f"{iv(r)}, {fmt_p(r['p_holm'])} ({r['verdict']})" for r in (c["metrics"][m] for m in METRICS)]
        lines.append(
            f"| {cid} | {verdict_text(c)} | {previous.get(cid, '-')} | {test} | {cells[0]} | {cells[1]} | {c['text']} |"
        )
    return lines


def method_lines(ev: dict) -> list[str]:
    return [
        "## Method (declared in `experiments/claims.py` before the runs that decide it)",
        "",
        "- Two co-primary metrics, per trial over the test's episode window: the mean of ln(steps per episode) "
        f"(lower is better; margin ln 1.1 = {MARGIN:.3f}, 10% fewer steps) and the mean return per episode "
        f"(higher is better; margin {RETURN_MARGIN['maze']} on the Maze, {RETURN_MARGIN['taxi']} on Taxi). Effects "
        'are signed so that positive means "as claimed".',
        "- Each metric decides on its own: **reproduced** when its Holm-adjusted p < "
        f"{ALPHA} (Holm across the family's primary tests, per metric); **not reproduced** when some component's "
        "95% interval lies wholly below its margin (non-inferiority: below minus the margin); **inconclusive** "
        "otherwise. A claim is reproduced (or not) only where both metrics say so; where they differ it is "
        "**mixed**, and the table names each metric's verdict.",
        "- Population: a maze claim's primary population is the honest layouts (Taxi: all its trials); A1 and "
        "M1, claims about a misleading teacher, are decided on the misleading layouts. The other layout classes "
        "and the layout-class x method interaction (effect on honest minus on misleading layouts, two-sided "
        "Welch t-test over the layouts' means) are the declared extension: shown, never deciding.",
        "- Trials are clustered by layout (Gymnasium's Taxi: by seed); estimate: mean over trials; interval: 95% "
        f"percentile bootstrap resampling whole layouts ({ev['n_boot']} resamples); p: one-sided t-test over the "
        "layouts' means. A test of several effects that must all hold (intersection-union) shows its weakest "
        "component (the largest p).",
        "- Robustness of the ln-steps decision (never deciding): Wilcoxon signed-rank instead of t, the per-trial "
        "median instead of the mean of ln steps, each with the same Holm factor; **fragile** where either flips "
        "it. MDE: the smallest true effect the design detects with 80% power at level alpha/m.",
        "",
    ]


def _metric_rows(label: str, by_metric: dict) -> list[str]:
    rows = []
    for m in METRICS:
        r = by_metric.get(m)
        if r:
            left = f" ({r['left_out']} of its comparisons have no such trials)" if r.get("left_out") else ""
            rows.append(f"| {label} | {m} | {iv(r)} | {fmt_p(r['p'])}{left} |")
    return rows


def claim_section(cid: str, c: dict, deciding: tuple[str, ...] = METRICS) -> list[str]:
    mark = (" (fragile)" if c.get("fragile") else "") + (UNSETTLED if c.get("expected_unsettled") else "")
    lines = [f"### {cid}: {c['verdict']}{mark}", "", c["text"], ""]
    if c["verdict"] == "not evaluated":
        return lines + ["(its conditions were not run)", ""]
    lines += [
        f"Primary: {c['primary_test']} ({c['kind']}; {c['layouts']} layouts).",
        "",
        "| population | metric | estimate [95% CI] | p (one-sided) |",
        "|---|---|---|---|",
    ]
    for m in METRICS:
        r = c["metrics"][m]
        lines.append(
            f"| {c['layouts']} (primary{'' if m in deciding else '; never decides'}) | {m} | {iv(r)} | "
            f"{fmt_p(r['p'])} (Holm {fmt_p(r['p_holm'])}, x"
            f"{r['holm_factor']}): **{r['verdict']}**; {r['trials']} trials in {r['clusters']} clusters, "
            f"MDE {r['mde']:.3f} against the margin {r['margin']:.3f} |"
        )
    for subset, by_metric in c["extension"]["populations"].items():
        lines += _metric_rows(f"{subset} (extension)", by_metric)
    lines.append("")
    inter = c["extension"]["interaction"]
    if any(inter.values()):
        lines += [
            "Layout class x method (effect on honest minus on misleading layouts; two-sided Welch p):",
            "",
            "| metric | comparison | honest | misleading | difference [95% CI] | p |",
            "|---|---|---|---|---|---|",
        ]
        for m in METRICS:
            for x in inter[m]:
                lines.append(
                    f"| {m} | {x['label']} | {x['honest']:+.3f} | {x['misleading']:+.3f} | "
                    f"{x['difference']:+.3f} [{x['ci'][0]:+.3f}, {x['ci'][1]:+.3f}] | "
                    f"{fmt_p(x['p_two_sided'])} |"
                )
        lines.append("")
    for m in METRICS:
        comps = c["metrics"][m]["components"]
        if len(comps) > 1:
            lines += [
                f"Components ({m}; all must hold): "
                + "; ".join(
                    f"{x['label']}: {x['estimate']:+.3f} [{x['ci'][0]:+.3f}, {x['ci'][1]:+.3f}] (p {fmt_p(x['p'])})"
                    for x in comps
                ),
                "",
            ]
    rob = c["metrics"]["ln steps"].get("robustness", {})
    if rob:
        lines += [
            "Robustness (ln steps, never deciding): "
            + "; ".join(
                f"{k}: {v['estimate']:+.3f}, Holm-factor p {fmt_p(v['p_adj'])} "
                f"({'reproduced' if v['reproduced'] else 'not'})"
                for k, v in rob.items()
            ),
            "",
        ]
    if c.get("secondary"):
        lines += [
            "| secondary test (never deciding) | metric | pooled | honest | misleading |",
            "|---|---|---|---|---|",
        ]
        for s in c["secondary"]:
            for m in METRICS:
                cells = [
                    f"{iv(r)} p {fmt_p(r['p'])}" if (r := s["by_layouts"].get(k, {}).get(m)) else "n/a"
                    for k in ("pooled", "honest", "misleading")
                ]
                lines.append(f"| {s['test']} ({s['kind']}) | {m} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines
