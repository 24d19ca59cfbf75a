"""Do results depend on the machine? Compare two reproductions run under different BLAS code paths.

    OPENBLAS_CORETYPE=Haswell python -m experiments reproduce --out A             (the reference)
    env -u OPENBLAS_CORETYPE python -m experiments reproduce --only COND --out B  (another code path)
    python -m experiments machines A B

For every trial of B's conditions: do its per-episode steps and returns equal A's bit for bit? Then every
claim is evaluated twice, on A's trials and on A's trials with B's conditions swapped in, and any verdict
that changes is listed. Writes A/machines.json, which REPORT.md shows when A is re-plotted.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from common.config import option

from experiments.conditions import BY_NAME, FULL, Scale
from experiments.declarations import of_run
from experiments.evaluate import evaluate_claims
from experiments.reproduce import collect
from experiments.trialcache import plan


def _conditions_in(out: str) -> list[str]:
    cache = os.path.join(out, "cache")
    return [c for c in BY_NAME if os.path.isdir(os.path.join(cache, c))]


def _scale_of(out: str) -> Scale:
    with open(os.path.join(out, "timing.json")) as fh:
        scale = json.load(fh)["scale"]
    scale.setdefault("taxi_random_episodes", scale["taxi_episodes"])  # runs before the two Taxi counts split
    # A run before the fresh layouts (25 November 2026) recorded no first_layout / seed_block: 0 and 1 then.
    return Scale(**{"first_layout": 0, "seed_block": 1, **scale})


def compare(dir_a: str, dir_b: str, n_boot: int = 2000) -> dict:
    timing = os.path.join(dir_a, "timing.json")
    scale = _scale_of(dir_a) if os.path.exists(timing) else FULL
    decl = of_run(json.load(open(timing)) if os.path.exists(timing) else {})  # its arms and claims
    names_a, names_b = _conditions_in(dir_a), _conditions_in(dir_b)
    conds_a = decl.conditions([BY_NAME[n] for n in names_a])
    conds_b = decl.conditions([BY_NAME[n] for n in names_b if n in names_a])
    cached_a, todo_a, _ = plan(conds_a, scale, os.path.join(dir_a, "cache"))
    cached_b, todo_b, _ = plan(conds_b, scale, os.path.join(dir_b, "cache"))
    if todo_a or todo_b:
        raise SystemExit(f"incomplete runs: {len(todo_a)} trials missing in A, {len(todo_b)} in B")
    rows = []
    for c in conds_b:
        for arm in c.arms:
            keys = [k for (cn, a, k) in cached_b if cn == c.name and a == arm]
            differ = [
                k
                for k in keys
                if cached_a[(c.name, arm, k)]["steps"] != cached_b[(c.name, arm, k)]["steps"]
                or cached_a[(c.name, arm, k)]["return"] != cached_b[(c.name, arm, k)]["return"]
            ]
            first = [
                int(
                    np.argmax(
                        np.array(cached_a[(c.name, arm, k)]["steps"]) != np.array(cached_b[(c.name, arm, k)]["steps"])
                    )
                )
                for k in differ
                if cached_a[(c.name, arm, k)]["steps"] != cached_b[(c.name, arm, k)]["steps"]
            ]
            rows.append(
                {
                    "cond": c.name,
                    "arm": arm,
                    "trials": len(keys),
                    "differ": len(differ),
                    "first_diverging_episode_median": float(np.median(first)) if first else None,
                }
            )
    data_a, _ = collect(conds_a, scale, cached_a)
    swapped = dict(cached_a)
    swapped.update(cached_b)
    data_b, _ = collect(conds_a, scale, swapped)
    va, vb = evaluate_claims(data_a, n_boot, decl), evaluate_claims(data_b, n_boot, decl)
    changed = {cid: [va[cid]["verdict"], vb[cid]["verdict"]] for cid in va if va[cid]["verdict"] != vb[cid]["verdict"]}
    est = {cid: [va[cid].get("estimate"), vb[cid].get("estimate")] for cid in va}
    n_diff, n_all = sum(r["differ"] for r in rows), sum(r["trials"] for r in rows)
    env_b = json.load(open(os.path.join(dir_b, "timing.json"))).get("env", {})
    env_a = json.load(open(os.path.join(dir_a, "timing.json"))).get("env", {})
    summary = (
        f"Run A: BLAS environment {env_a}; run B: {env_b} (the same CPU, another OpenBLAS kernel). Of the "
        f"{n_all} trials of {', '.join(names_b)} run in both, {n_diff} differ in at least one episode "
        "(rounding in the matrix products, amplified by training). Verdicts computed with B's trials in "
        "place of A's: "
        + (
            "no verdict changes."
            if not changed
            else "changed: " + "; ".join(f"{k}: {a} -> {b}" for k, (a, b) in changed.items()) + "."
        )
    )
    timing_a = json.load(open(os.path.join(dir_a, "timing.json")))
    return {
        "summary": summary,
        "rows": rows,
        "changed": changed,
        "estimates": est,
        "env_a": env_a,
        "env_b": env_b,
        "commit": timing_a.get("commit"),
        "scale": timing_a.get("scale"),
    }


@dataclass(frozen=True)
class MachinesConfig:
    """Which trials of two reproductions (e.g. another OPENBLAS_CORETYPE) differ, and whether any verdict does;
    writes DIR_A/machines.json."""

    dir_a: str = option("", "the first reproduction's output directory", positional=True)
    dir_b: str = option("", "the second one's", positional=True)


def main(args: MachinesConfig) -> int:
    result = compare(args.dir_a, args.dir_b)
    with open(os.path.join(args.dir_a, "machines.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    print(result["summary"])
    for r in result["rows"]:
        print(f"  {r['cond']} {r['arm']}: {r['differ']} of {r['trials']} trials differ")
    return 0


if __name__ == "__main__":
    from common.config import moved

    moved("python -m experiments machines")
