"""Computes the declared claims (experiments/claims.py) from the trials: estimates, intervals, Holm, verdicts.

Input `Data`: condition -> arm -> `ArmData` (per-trial arrays, trials aligned across arms and across the
conditions of one layout set: trial k is the same layout and seed everywhere). Each claim is tested on
both co-primary metrics (ln steps, return) on its primary population, then on the other layout classes
(the declared extension) with the layout-class x method interaction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.envs.maze import layout_kind
from experiments import stats
from experiments.claims import ALPHA, MARGIN, METRICS, RETURN_MARGIN, Effect, Test
from experiments.declarations import Declaration, UNRECORDED, get

N_BOOT = 2000
SUBSETS = ("pooled", "honest", "misleading")
METRIC_VARIANT = {"ln steps": "mean_log", "return": "return"}
ROBUSTNESS = {"wilcoxon": ("mean_log", "wilcoxon"), "median ln steps": ("median_log", "t")}
"""Other reasonable rules for the ln-steps decision (shown as "fragile" where they flip it; never deciding)."""
REPRODUCED, NOT_REPRODUCED, INCONCLUSIVE, NOT_EVALUATED, MIXED = (
    "reproduced",
    "not reproduced",
    "inconclusive",
    "not evaluated",
    "mixed",
)


@dataclass
class ArmData:
    steps: np.ndarray  # [n, E] steps per episode
    returns: np.ndarray  # [n, E]
    layouts: np.ndarray  # [n] layout (maze) or task / seed (taxi)
    clusters: np.ndarray  # [n] resampling cluster
    stop: int | None
    taxi: bool = False


Data = dict[str, dict[str, ArmData]]


def window(E: int, name: str, stop: int | None) -> slice:
    if name == "all":
        return slice(0, E)
    if name == "after-stop":
        return slice(stop, E)
    if name == "before":
        return slice(max(0, stop - 10), stop)
    if name in ("after", "last"):
        return slice(max(0, E - 10), E)
    if name == "first":
        return slice(0, min(10, E))
    raise ValueError(f"unknown window {name!r}")


def trial_metric(a: ArmData, win: str, variant: str) -> np.ndarray:
    """Per-trial metric over the window, oriented so that lower is better."""
    s = window(a.steps.shape[1], win, a.stop)
    if variant == "mean_log":
        return stats.log_steps(a.steps[:, s]).mean(axis=1)
    if variant == "median_log":
        return np.median(stats.log_steps(a.steps[:, s]), axis=1)
    if variant == "return":
        return -a.returns[:, s].mean(axis=1)
    raise ValueError(variant)


def _arm(data: Data, cond: str, arm: str, test_window: str) -> tuple[ArmData, str]:
    name, _, win = arm.partition("@")
    return data[cond][name], (win or test_window)


def effect_values(data: Data, e: Effect, test_window: str, variant: str) -> tuple[np.ndarray, np.ndarray, ArmData]:
    """(per-trial effect, clusters, the first term's arm data for layouts)."""
    total, ref = None, None
    for coef, cond, arm in e.terms:
        a, win = _arm(data, cond, arm, test_window)
        if ref is None:
            ref = a
        elif not np.array_equal(ref.layouts, a.layouts):
            raise ValueError(f"{e.label}: trials of {cond} are not paired with the others")
        v = coef * trial_metric(a, win, variant)
        total = v if total is None else total + v
    return total, ref.clusters, ref


def available(data: Data, t: Test) -> bool:
    return all(cond in data and arm.partition("@")[0] in data[cond] for e in t.effects for _, cond, arm in e.terms)


def subset_mask(ref: ArmData, subset: str) -> np.ndarray | None:
    if subset == "pooled":
        return np.ones(len(ref.layouts), bool)
    if ref.taxi:
        return None
    mask = np.array([layout_kind(int(L)) == subset for L in ref.layouts])
    return mask if mask.any() else None


def margin_of(ref: ArmData, variant: str) -> float:
    return RETURN_MARGIN["taxi" if ref.taxi else "maze"] if variant == "return" else MARGIN


def _component(v: np.ndarray, cl: np.ndarray, kind: str, margin: float, how: str, n_boot: int) -> dict:
    """One effect on one population: estimate, bootstrap interval (layouts resampled), se, one-sided p."""
    ids, cm, counts = stats.cluster_means(v, cl)
    shift = margin if kind == "noninferior" else 0.0
    b = stats.cluster_bootstrap(v, cl, n_boot)
    return {
        "estimate": float(v.mean()),
        "ci": b["ci"],
        "se": b["se"],
        "margin": margin,
        "p": stats.one_sided_p(cm + shift, how) if len(cm) >= 2 else 1.0,
        "clusters": int(len(ids)),
        "trials": int(len(v)),
    }


def _population(ref: ArmData, subset: str) -> np.ndarray | None:
    """Trials of the population; Taxi (no layout classes) counts all its trials as honest."""
    if ref.taxi:
        return subset_mask(ref, "pooled") if subset in ("honest", "pooled") else None
    return subset_mask(ref, subset)


def effect_on(data: Data, e: Effect, t: Test, subset: str, variant: str) -> tuple | None:
    """(per-trial effect, clusters, margin) on a population, or None where it has no such trials."""
    v, cl, ref = effect_values(data, e, t.window, variant)
    mask = _population(ref, subset)
    if mask is None or mask.sum() < 2 or not np.all(np.isfinite(v[mask])):
        return None  # no such layouts, or an empty episode window (a run shorter than the test needs)
    return v[mask], cl[mask], margin_of(ref, variant)


def run_test(
    data: Data,
    t: Test,
    subset: str | None = None,
    metric: str = "ln steps",
    n_boot: int = N_BOOT,
    rule: tuple[str, str] | None = None,
) -> dict | None:
    """A test on one population and metric: every component, and the weakest (largest p) as the test's
    estimate, interval and p (intersection-union). Components without trials there are left out (Taxi on
    misleading layouts); None when none is left."""
    variant, how = rule or (METRIC_VARIANT[metric], "t")
    subset = subset or t.layouts
    comps = []
    for e in t.effects:
        got = effect_on(data, e, t, subset, variant)
        if got is not None:
            comps.append(dict(_component(*got[:2], t.kind, got[2], how, n_boot), label=e.label))
    if not comps:
        return None
    weakest = max(comps, key=lambda c: c["p"])
    return {k: weakest[k] for k in ("estimate", "ci", "se", "p", "margin", "clusters", "trials")} | {
        "components": comps,
        "left_out": len(t.effects) - len(comps),
    }


def interaction(data: Data, t: Test, metric: str, n_boot: int) -> list[dict]:
    """Layout class x method, per maze component: effect on honest minus on misleading layouts; two-sided
    Welch t-test over the two classes' layout means; bootstrap resampling layouts within each class."""
    from scipy import stats as sps  # (here: scipy.stats takes a second to import)

    variant = METRIC_VARIANT[metric]
    out = []
    for e in t.effects:
        h, m = effect_on(data, e, t, "honest", variant), effect_on(data, e, t, "misleading", variant)
        if h is None or m is None:
            continue
        _, hm, _ = stats.cluster_means(h[0], h[1])
        _, mm, _ = stats.cluster_means(m[0], m[1])
        bh = stats.cluster_bootstrap(h[0], h[1], n_boot)["boot"]
        bm = stats.cluster_bootstrap(m[0], m[1], n_boot, seed=stats.BOOT_SEED + 1)["boot"]
        lo, hi = np.quantile(bh - bm, [0.025, 0.975])
        p = float(sps.ttest_ind(hm, mm, equal_var=False).pvalue) if len(hm) > 1 and len(mm) > 1 else 1.0
        out.append(
            {
                "label": e.label,
                "honest": float(h[0].mean()),
                "misleading": float(m[0].mean()),
                "difference": float(h[0].mean() - m[0].mean()),
                "ci": [float(lo), float(hi)],
                "p_two_sided": p if np.isfinite(p) else 1.0,
            }
        )
    return out


def decide(kind: str, r: dict, p_adj: float) -> str:
    """One metric's verdict: reproduced (Holm p < ALPHA); not reproduced where some component's interval
    lies wholly below its margin (noninferior: below minus its margin); inconclusive otherwise."""
    if p_adj < ALPHA:
        return REPRODUCED
    below = any(c["ci"][1] < (c["margin"] if kind == "greater" else -c["margin"]) for c in r["components"])
    return NOT_REPRODUCED if below else INCONCLUSIVE


def combine(verdicts: dict[str, str]) -> str:
    """The claim's verdict: the metrics' common verdict, or mixed where they differ."""
    distinct = set(verdicts.values())
    return distinct.pop() if len(distinct) == 1 else MIXED


def _metric_record(data: Data, c, metric: str, r: dict, p_adj: float, factor: int, m: int, n_boot: int) -> dict:
    rec = dict(
        r, p_holm=p_adj, holm_factor=factor, verdict=decide(c.primary.kind, r, p_adj), mde=stats.mde(r["se"], ALPHA / m)
    )
    if metric == "ln steps":
        rec["robustness"] = {}
        for name, rule in ROBUSTNESS.items():
            alt = run_test(data, c.primary, metric=metric, n_boot=n_boot, rule=rule)
            if alt is not None:
                rec["robustness"][name] = {
                    "estimate": alt["estimate"],
                    "p_adj": min(1.0, factor * alt["p"]),
                    "reproduced": min(1.0, factor * alt["p"]) < ALPHA,
                }
    return rec


def _extension(data: Data, t: Test, n_boot: int, metrics: tuple[str, ...] = METRICS) -> dict:
    """The other populations and the interaction, per metric (never deciding)."""
    return {
        "populations": {
            s: {metric: run_test(data, t, s, metric, n_boot) for metric in metrics} for s in SUBSETS if s != t.layouts
        },
        "interaction": {metric: interaction(data, t, metric, n_boot) for metric in metrics},
    }


def evaluate_claims(data: Data, n_boot: int = N_BOOT, declaration: Declaration | None = None) -> dict:
    """Every claim of the declaration (default: 25 November's): each metric (Holm within its family, per metric),
    the claim's verdict from the deciding metrics, robustness, the extension (other layout classes, interaction)
    and the secondary tests."""
    decl = declaration or get(UNRECORDED)
    out: dict = {}
    for family in decl.families:
        claims = [c for c in decl.claims if c.family == family]
        results = {
            metric: {
                c.cid: run_test(data, c.primary, metric=metric, n_boot=n_boot) if available(data, c.primary) else None
                for c in claims
            }
            for metric in decl.metrics
        }
        for c in claims:
            out[c.cid] = _claim_record(data, decl, c, results, n_boot)
    return out


def _claim_record(data: Data, decl: Declaration, c, results: dict, n_boot: int) -> dict:
    rec: dict = {
        "family": c.family,
        "text": c.text,
        "primary_test": c.primary.text,
        "kind": c.primary.kind,
        "layouts": c.primary.layouts,
        "window": c.primary.window,
    }
    if c.cid in decl.expected_unsettled:
        rec["expected_unsettled"] = True
    if results[decl.metrics[0]][c.cid] is None:
        rec["verdict"] = NOT_EVALUATED
        return rec
    rec["metrics"] = {}
    for metric in decl.metrics:
        pvals = {cid: r["p"] for cid, r in results[metric].items() if r is not None}
        ranked = sorted(pvals, key=lambda k: pvals[k])
        rec["metrics"][metric] = _metric_record(
            data,
            c,
            metric,
            results[metric][c.cid],
            stats.holm(pvals)[c.cid],
            len(ranked) - ranked.index(c.cid),
            len(ranked),
            n_boot,
        )
    rec["verdict"] = combine({m: r["verdict"] for m, r in rec["metrics"].items() if m in decl.deciding})
    ln = rec["metrics"]["ln steps"]
    rec["fragile"] = any(a["reproduced"] != (ln["verdict"] == REPRODUCED) for a in ln["robustness"].values())
    rec["extension"] = _extension(data, c.primary, n_boot, decl.metrics)
    rec["secondary"] = [
        {
            "test": t.text,
            "kind": t.kind,
            "window": t.window,
            "layouts": t.layouts,
            "by_layouts": {
                s: {metric: run_test(data, t, s, metric, n_boot) for metric in decl.metrics} for s in SUBSETS
            },
        }
        for t in c.secondary
        if available(data, t)
    ]
    return rec
