"""The declared tests of a browser comparison: each run's measure (episodes to the goal, or to a good episode),
paired differences with a one-sided Wilcoxon signed-rank p per test, and Holm across the declared tests."""

from __future__ import annotations

import numpy as np

from services.console.design import Design


def episodes_to_goal(row: dict, design: Design) -> int:
    """The declared measure of one run (fewer is better)."""
    if design.measure == "goals":
        reached = np.flatnonzero(row["reached_goal"][: design.episodes])
        if len(reached) >= design.goals:
            return int(reached[design.goals - 1]) + 1
        return design.episodes + design.goals - len(reached)
    return row["first_good_episode"] or design.episodes + 1


MEASURE_TITLES = {
    "first_good": "first episode within {f:g}x shortest path (never = {n})",
    "goals": "episodes to reach the goal {k} times",
}


def one_test(rows: list[dict], design: Design, person: str | None = None, kind: str | None = None) -> dict:
    """Paired differences (first primary arm minus second) of the measure, over the pairs of `person` on layouts of
    `kind` (None: all), and their one-sided Wilcoxon signed-rank p (zero differences dropped)."""
    from scipy import stats

    from common.envs.maze import layout_kind

    by = {(r["arm"], r.get("person"), r["layout"], r["seed"]): r for r in rows}
    first, second = design.primary
    pairs = [(lay, s) for lay, s in design.pairs if kind is None or layout_kind(lay) == kind]
    d = np.array(
        [
            episodes_to_goal(by[first, person, lay, s], design) - episodes_to_goal(by[second, person, lay, s], design)
            for lay, s in pairs
        ]
    )
    nonzero = d[d != 0]
    p = float(stats.wilcoxon(nonzero, alternative="greater").pvalue) if len(nonzero) else 1.0
    sign = (
        stats.binomtest(int((nonzero > 0).sum()), len(nonzero), alternative="greater").pvalue if len(nonzero) else 1.0
    )
    return {
        "person": person,
        "kind": kind,
        "differences": d.tolist(),
        "mean": float(d.mean()),
        "wins": int((d > 0).sum()),
        "ties": int((d == 0).sum()),
        "losses": int((d < 0).sum()),
        "wilcoxon_p": p,
        "sign_p": float(sign),
    }


def holm(pvalues: list[float], alpha: float) -> list[float]:
    """Holm's step-down thresholds: the i-th smallest p is compared with alpha / (m - i) while all before passed;
    returns each test's threshold (0 for a test never reached: the step-down stopped before it)."""
    order = np.argsort(pvalues, kind="stable")
    thresholds, passing = [0.0] * len(pvalues), True
    for rank, i in enumerate(order):
        if passing:
            thresholds[i] = alpha / (len(pvalues) - rank)
            passing = pvalues[i] < thresholds[i]
    return thresholds


def declared_tests(rows: list[dict], design: Design) -> list[dict]:
    """Every test the design declares, each with the threshold its multiplicity rule gives it and its verdict."""
    tests = [one_test(rows, design, person, kind) for person, kind in design.tests()]
    if design.multiplicity == "holm":
        thresholds = holm([t["wilcoxon_p"] for t in tests], design.alpha)
    else:
        thresholds = [design.alpha / design.looks] * len(tests)
    for t, alpha in zip(tests, thresholds):
        t["alpha"] = alpha
        t["verdict"] = "fewer episodes" if t["wilcoxon_p"] < alpha and t["mean"] > 0 else "not shown"
    return tests


def secondary_tests(rows: list[dict], design: Design) -> list[dict]:
    """Shown, never deciding: each person on each layout kind, where the declared tests pool the kinds."""
    if design.multiplicity != "holm" or design.tests_by != "person":
        return []
    return [one_test(rows, design, person, kind) for person in design.people for kind in design.kinds()]


def primary_test(rows: list[dict], design: Design) -> dict:
    """The one declared test of a `looks` design."""
    return declared_tests(rows, design)[0]
