"""Computes the declared claims (experiments/claims.py) from the trials: estimates, intervals, Holm, verdicts.

Input `Data`: condition -> arm -> `ArmData` (per-trial arrays, trials aligned across arms and across the
conditions of one layout set: trial k is the same layout and seed everywhere).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.envs.maze import layout_kind
from experiments import stats
from experiments.claims import ALPHA, CLAIMS, FAMILIES, MARGIN, Effect, Test

N_BOOT = 2000
SUBSETS = ("pooled", "honest", "misleading")
VARIANTS = {"primary": ("mean_log", "t"), "wilcoxon": ("mean_log", "wilcoxon"),
            "median ln steps": ("median_log", "t"), "mean return": ("return", "t")}
REPRODUCED, NOT_REPRODUCED, INCONCLUSIVE, NOT_EVALUATED = ("reproduced", "not reproduced", "inconclusive",
                                                           "not evaluated")


@dataclass
class ArmData:
    steps: np.ndarray    # [n, E] steps per episode
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


def run_test(data: Data, t: Test, subset: str | None = None, variant: str = "primary",
             n_boot: int = N_BOOT) -> dict | None:
    """Estimate, 95% interval, se and one-sided p of a test on one layout subset (None: not applicable)."""
    metric, how = VARIANTS[variant]
    subset = subset or t.layouts
    cols, ps, estimates, clusters = [], [], [], None
    for e in t.effects:
        v, cl, ref = effect_values(data, e, t.window, metric)
        mask = subset_mask(ref, subset)
        if mask is None or mask.sum() < 2:
            return None
        v, cl = v[mask], cl[mask]
        if not np.all(np.isfinite(v)):
            return None  # an empty episode window (a run shorter than the test needs)
        shift = MARGIN if t.kind == "noninferior" else 0.0
        _, cm, _ = stats.cluster_means(v, cl)
        ps.append(stats.one_sided_p(cm + shift, how) if len(cm) >= 2 else 1.0)
        estimates.append(float(v.mean()))
        cols.append(v)
        clusters = cl
    # Intersection-union: the smallest effect, resampled jointly (same layouts for every effect).
    ids, means, counts = stats.cluster_means(np.stack(cols, axis=1), clusters)
    w = stats.cluster_boot_weights(len(ids), n_boot) * counts[None, :]
    boot = ((w @ means) / w.sum(axis=1, keepdims=True)).min(axis=1)
    lo, hi = np.quantile(boot, [0.025, 0.975])
    return {"estimate": min(estimates), "ci": [float(lo), float(hi)], "se": float(boot.std(ddof=1)),
            "p": max(ps), "clusters": int(len(ids)), "trials": int(len(clusters)),
            "components": [{"label": e.label, "estimate": est, "p": p} for e, est, p in zip(t.effects, estimates, ps)]}


def decide(kind: str, ci: list[float], p_adj: float) -> str:
    if p_adj < ALPHA:
        return REPRODUCED
    bound = MARGIN if kind == "greater" else -MARGIN
    return NOT_REPRODUCED if ci[1] < bound else INCONCLUSIVE


def evaluate_claims(data: Data, n_boot: int = N_BOOT) -> dict:
    """Every claim: primary test (Holm within its family), fragility, MDE, secondary tests."""
    out: dict = {}
    for family in FAMILIES:
        claims = [c for c in CLAIMS if c.family == family]
        primaries = {c.cid: run_test(data, c.primary, n_boot=n_boot) if available(data, c.primary) else None
                     for c in claims}
        pvals = {cid: r["p"] for cid, r in primaries.items() if r is not None}
        adjusted = stats.holm(pvals)
        ranked = sorted(pvals, key=lambda k: pvals[k])
        m = len(ranked)
        for c in claims:
            r = primaries[c.cid]
            rec = {"family": family, "text": c.text, "primary_test": c.primary.text, "kind": c.primary.kind,
                   "layouts": c.primary.layouts, "window": c.primary.window}
            if r is None:
                rec["verdict"] = NOT_EVALUATED
                out[c.cid] = rec
                continue
            factor = m - ranked.index(c.cid)
            rec.update(r, p_holm=adjusted[c.cid], holm_factor=factor,
                       verdict=decide(c.primary.kind, r["ci"], adjusted[c.cid]),
                       mde=stats.mde(r["se"], ALPHA / m), margin=MARGIN)
            rec["alternatives"] = {}
            for variant in VARIANTS:
                if variant == "primary":
                    continue
                alt = run_test(data, c.primary, variant=variant, n_boot=n_boot)
                if alt is not None:
                    rec["alternatives"][variant] = {"estimate": alt["estimate"], "p_adj": min(1.0, factor * alt["p"]),
                                                    "reproduced": min(1.0, factor * alt["p"]) < ALPHA}
            rec["fragile"] = any(a["reproduced"] != (rec["verdict"] == REPRODUCED)
                                 for a in rec["alternatives"].values())
            rec["by_layouts"] = {s: run_test(data, c.primary, subset=s, n_boot=n_boot) for s in SUBSETS
                                 if s != c.primary.layouts}
            rec["secondary"] = []
            for t in c.secondary:
                if not available(data, t):
                    continue
                rows = {s: run_test(data, t, subset=s, n_boot=n_boot) for s in SUBSETS}
                rec["secondary"].append({"test": t.text, "kind": t.kind, "window": t.window,
                                         "by_layouts": {s: r for s, r in rows.items() if r is not None}})
            out[c.cid] = rec
    return out
