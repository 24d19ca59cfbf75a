"""`python -m experiments power`: how large must the confirmatory design be for its verdicts not to flip?

Issue 34 asks for a design so large that two independent runs of it would agree on every claim's verdict at least
90% of the time. This estimates that agreement from the published runs' per-trial tables: at each candidate size
(maze layouts x seeds per layout) it draws many replicate runs by resampling the run's clusters (layouts;
Gymnasium's Taxi: seeds) with replacement, decides every claim on each replicate by the claims' own rules, and
counts how often two replicates give the same verdict.

The verdict rules are those of `experiments/claims.py` and `experiments/evaluate.py` (`decide`, Holm per family,
the one-sided t-test over cluster means, the cluster bootstrap interval against the margin), with the two changes
the new declaration makes: ln steps is the single primary metric (return never decides), and the paper's claims
C1-C6 are decided on the paper's population, every layout pooled. D1-D3, A1 and M1 keep their declared
populations.

Resampling unit: the cluster, as the analysis resamples it. A maze layout's S seeds are drawn from that layout's
trials; the published tables have one seed per layout, so a drawn layout's seeds repeat its one trial and count as
one (conservative: seeds are credited with none of the variance, which the tables cannot split between layout and
seed). Condition sets with fewer layouts (the delay observers: 16) and Gymnasium's Taxi (one trial per seed) grow
in proportion: layouts by L / L0, Taxi seeds by L x S / L0 (L0: today's maze layouts).

Agreement of a claim at a size: the probability that two independent replicates give the same verdict, estimated
without bias from the verdict counts n_v over R replicates as sum n_v (n_v - 1) / (R (R - 1)).
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from common.config import option
from experiments import stats
from experiments.claims import ALPHA, CLAIMS, FAMILIES
from experiments.evaluate import N_BOOT, Data, decide, effect_on

ROOT = Path(__file__).resolve().parents[1]
PAPER_POPULATION = "pooled"
"""The population of the paper's claims C1-C6 in the new declaration (issue 34): every layout."""
TARGET = 0.9


@dataclass(frozen=True)
class PowerConfig:
    """Estimate, by resampling the published runs' layouts, how often two runs of a design of each candidate size
    would agree on every claim's verdict; choose the smallest size where every claim agrees at least 90% of the
    time in every table."""

    tables: tuple[str, ...] = option(
        ("docs/results/trials.csv.xz", "git:2e65dd4:docs/results/trials.csv.gz"),
        "per-trial tables: a path, or git:COMMIT:PATH (read with git show into .cache/power/); the defaults are "
        "the two published runs (docs/results/HISTORY.md: 25 Nov 23:46 and 21:07)",
        nargs="+",
    )
    sizes: tuple[str, ...] = option(
        ("60x1", "120x2", "240x2", "360x2", "480x2", "720x2", "960x2"),
        "candidate sizes, LAYOUTSxSEEDS (maze layouts x seeds per layout)",
        nargs="+",
    )
    replicates: int = option(250, "replicate runs drawn per table and size")
    seed: int = option(34, "seed of the resampling (the same seed gives the same figures)")
    n_boot: int = option(N_BOOT, "bootstrap resamples of each replicate's interval (the analysis uses 2000)")
    out: str = option("docs/results", "where power.json and power.png are written")


@dataclass
class Component:
    """One effect of a claim's primary test on its population, per cluster of its condition set."""

    universe: str  # the condition set whose clusters are drawn together (one draw per replicate)
    trials: np.ndarray  # [clusters, most trials in a cluster] per-trial effect, NaN past a cluster's count
    counts: np.ndarray  # [clusters] trials per cluster
    member: np.ndarray  # [clusters] whether the cluster is in the claim's population
    margin: float


@dataclass
class ClaimModel:
    cid: str
    family: str
    kind: str  # greater | noninferior
    components: list[Component]


def parse_size(text: str) -> tuple[int, int]:
    layouts, _, seeds = text.partition("x")
    try:
        size = int(layouts), int(seeds or 1)
    except ValueError:
        raise ValueError(f"size {text!r}: LAYOUTSxSEEDS, such as 240x2") from None
    if min(size) < 1:
        raise ValueError(f"size {text!r}: at least one layout and one seed")
    return size


def load_table(spec: str, root: Path = ROOT) -> Path:
    """The table's path; `git:COMMIT:PATH` is read from the repository's history once into .cache/power/."""
    if not spec.startswith("git:"):
        return Path(spec)
    _, commit, path = spec.split(":", 2)
    cached = root / ".cache" / "power" / f"{commit}-{Path(path).name}"
    if not cached.exists():
        cached.parent.mkdir(parents=True, exist_ok=True)
        blob = subprocess.run(["git", "-C", str(root), "show", f"{commit}:{path}"], capture_output=True, check=False)
        if blob.returncode:
            raise ValueError(f"{spec}: {blob.stderr.decode().strip()}")
        cached.with_suffix(".tmp").write_bytes(blob.stdout)
        cached.with_suffix(".tmp").replace(cached)
    return cached


def _component(v: np.ndarray, clusters: np.ndarray, member_trials: np.ndarray, margin: float, universe: str):
    ids, inverse, counts = np.unique(clusters, return_inverse=True, return_counts=True)
    trials = np.full((len(ids), counts.max()), np.nan)
    slot = np.zeros(len(ids), int)
    for value, c in zip(v, inverse):
        trials[c, slot[c]] = value
        slot[c] += 1
    member = np.zeros(len(ids), bool)
    member[inverse[member_trials]] = True
    return Component(universe, trials, counts, member, margin)


def _layout_set(clusters: np.ndarray) -> str:
    """The name of a condition set's layouts (the maze conditions share one; the delay observers' is smaller)."""
    ids = np.unique(clusters)
    return f"{len(ids)} layouts {ids.min()}-{ids.max()}"


def claim_models(data: Data) -> list[ClaimModel]:
    """Every claim whose primary test's conditions are in `data`, as ln-steps components on its population."""
    models = []
    for c in CLAIMS:
        test = c.primary
        population = PAPER_POPULATION if c.family == "paper" else test.layouts
        comps = []
        for e in test.effects:
            everyone = effect_on(data, e, test, "pooled", "mean_log")
            mine = effect_on(data, e, test, population, "mean_log")
            if everyone is None or mine is None:
                continue
            v, clusters, margin = everyone
            cond = e.terms[0][1]
            member = np.isin(clusters, mine[1])
            universe = "taxi" if next(iter(data[cond].values())).taxi else _layout_set(clusters)
            comps.append(_component(v, clusters, member, margin, universe))
        if comps:
            models.append(ClaimModel(c.cid, c.family, test.kind, comps))
    return models


def _draw(n_clusters: int, size: int, seeds: int, counts: np.ndarray, rng: np.random.Generator):
    """(clusters drawn with replacement [size], trials drawn within each [size, seeds])."""
    picked = rng.integers(0, n_clusters, size)
    within = (rng.random((size, seeds)) * counts[picked, None]).astype(int)
    return picked, within


def universe_sizes(models: list[ClaimModel], layouts: int, seeds: int) -> dict[str, tuple[int, int]]:
    """(clusters, trials drawn per cluster) of each condition set at a size of `layouts` x `seeds`."""
    n0 = {comp.universe: len(comp.counts) for m in models for comp in m.components}
    maze0 = max((n for u, n in n0.items() if u != "taxi"), default=layouts)
    return {
        u: (
            (max(2, round(n * layouts * seeds / maze0)), 1)
            if u == "taxi"
            else (max(2, round(n * layouts / maze0)), seeds)
        )
        for u, n in n0.items()
    }


def replicate_verdicts(
    models: list[ClaimModel], sizes: dict[str, tuple[int, int]], rng: np.random.Generator, n_boot: int = N_BOOT
) -> dict[str, str]:
    """One replicate run: clusters drawn per condition set, then every claim decided by its rules (the weakest
    component's one-sided t-test p, Holm within the family; not reproduced where a component's bootstrap interval
    lies below its margin)."""
    draws = {}
    for m in models:
        for comp in m.components:
            if comp.universe not in draws:
                draws[comp.universe] = _draw(len(comp.counts), *sizes[comp.universe], comp.counts, rng)
    results: dict[str, dict] = {}
    for m in models:
        comps = []
        for comp in m.components:
            picked, within = draws[comp.universe]
            keep = comp.member[picked]
            x = comp.trials[picked[keep, None], within[keep]].mean(axis=1)
            shift = comp.margin if m.kind == "noninferior" else 0.0
            p = stats.one_sided_p(x + shift) if len(x) >= 2 else 1.0
            ci = stats.cluster_bootstrap(x, np.arange(len(x)), n_boot)["ci"] if len(x) >= 2 else [np.nan, np.nan]
            comps.append({"p": p, "ci": ci, "margin": comp.margin})
        results[m.cid] = {"p": max(c["p"] for c in comps), "components": comps}
    verdicts = {}
    for family in FAMILIES:
        mine = [m for m in models if m.family == family]
        adjusted = stats.holm({m.cid: results[m.cid]["p"] for m in mine}) if mine else {}
        for m in mine:
            verdicts[m.cid] = decide(m.kind, results[m.cid], adjusted[m.cid])
    return verdicts


def agreement(verdicts: list[str]) -> float:
    """The probability that two independent replicates give the same verdict (unbiased from the counts)."""
    n = len(verdicts)
    if n < 2:
        raise ValueError("agreement needs at least two replicates")
    _, counts = np.unique(verdicts, return_counts=True)
    return float((counts * (counts - 1)).sum() / (n * (n - 1)))


def curve(
    models: list[ClaimModel], sizes: list[tuple[int, int]], replicates: int, seed: int, n_boot: int, on_replicate=None
) -> list[dict]:
    """Per size: each claim's agreement and verdict counts over `replicates` replicate runs (seeded per size)."""
    out = []
    for i, (layouts, seeds) in enumerate(sizes):
        rng = np.random.default_rng([seed, i])
        per = universe_sizes(models, layouts, seeds)
        runs = []
        for _ in range(replicates):
            runs.append(replicate_verdicts(models, per, rng, n_boot))
            if on_replicate:
                on_replicate()
        claims: dict[str, dict] = {}
        for m in models:
            said = [r[m.cid] for r in runs]
            names, counts = np.unique(said, return_counts=True)
            claims[m.cid] = {"agreement": agreement(said), "verdicts": dict(zip(names.tolist(), counts.tolist()))}
        out.append(
            {
                "layouts": layouts,
                "seeds": seeds,
                "clusters": {u: n for u, (n, _) in per.items()},
                "claims": claims,
                "all_agree_min": min(c["agreement"] for c in claims.values()),
            }
        )
    return out


def first_reaching(rows: list[dict], cid: str, target: float = TARGET) -> dict | None:
    """The smallest size (in trials) from which on the claim agrees at least `target` at every larger size too."""
    ordered = sorted(rows, key=lambda r: r["layouts"] * r["seeds"])
    for i, r in enumerate(ordered):
        if all(later["claims"][cid]["agreement"] >= target for later in ordered[i:]):
            return {"layouts": r["layouts"], "seeds": r["seeds"]}
    return None


def choose(results: dict[str, list[dict]], target: float = TARGET) -> dict:
    """Per claim and table, the first size from which it agrees at least `target`; the chosen size is the largest
    of them (None where some claim reaches it at no candidate size, which are then named)."""
    reaching = {
        spec: {cid: first_reaching(rows, cid, target) for cid in rows[0]["claims"]} for spec, rows in results.items()
    }
    short = sorted({cid for per in reaching.values() for cid, size in per.items() if size is None})
    sizes = [s for per in reaching.values() for s in per.values() if s is not None]
    largest = max(sizes, key=lambda s: s["layouts"] * s["seeds"]) if sizes else None
    return {
        "size": None if short else largest,
        "never_reached": short,
        "largest_reached": largest,
        "per_claim": reaching,
    }


def figure(results: dict[str, list[dict]], path: Path, target: float = TARGET) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6.5 * len(results), 4.8), squeeze=False, sharey=True)
    for ax, (name, rows) in zip(axes[0], results.items()):
        x = [r["layouts"] * r["seeds"] for r in rows]
        colours = plt.get_cmap("tab20")  # 20 distinct colours: one per claim
        for i, cid in enumerate(rows[0]["claims"]):
            ax.plot(
                x,
                [r["claims"][cid]["agreement"] for r in rows],
                marker="os^"[i % 3],
                color=colours(i),
                linestyle="-" if cid.startswith("C") else "--",
                label=cid,
            )
        ax.axhline(target, color="k", linestyle="--", linewidth=1)
        ax.set(
            xlabel="maze trials per arm and condition (layouts x seeds)",
            ylabel="agreement of two runs",
            title=name,
            ylim=(0, 1.02),
        )
        ax.set_xticks(x, [f"{r['layouts']}x{r['seeds']}" for r in rows], rotation=45, fontsize=8)
    axes[0][-1].legend(fontsize=8, ncol=2, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _print(name: str, rows: list[dict]) -> None:
    cids = list(rows[0]["claims"])
    print(f"\n{name}: agreement of two runs' verdicts (ln steps; C1-C6 on every layout)")
    print("size      " + " ".join(f"{c:>5}" for c in cids) + "   min")
    for r in rows:
        cells = " ".join(f"{r['claims'][c]['agreement']:5.2f}" for c in cids)
        print(f"{r['layouts']:>4}x{r['seeds']:<4} {cells}  {r['all_agree_min']:.2f}")


def _print_choice(chosen: dict) -> None:
    def text(size: dict | None) -> str:
        return f"{size['layouts']}x{size['seeds']}" if size else "never"

    print(f"\nfirst size from which each claim agrees at least {TARGET:.0%} (per table):")
    for spec, per in chosen["per_claim"].items():
        print(f"  {spec}: " + ", ".join(f"{cid} {text(size)}" for cid, size in per.items()))
    if chosen["size"]:
        print(f"chosen: {text(chosen['size'])} (layouts x seeds per layout)")
    else:
        print(
            f"no candidate size reaches {TARGET:.0%} for {', '.join(chosen['never_reached'])}; every other claim "
            f"does by {text(chosen['largest_reached'])}"
        )


def main(cfg: PowerConfig) -> int:
    from tqdm import tqdm

    from experiments.trials import read_table

    sizes = [parse_size(s) for s in cfg.sizes]
    tables = {spec: read_table(str(load_table(spec))) for spec in cfg.tables}
    models = {spec: claim_models(t.data) for spec, t in tables.items()}
    results = {}
    with tqdm(total=len(tables) * len(sizes) * cfg.replicates, desc="replicates", file=sys.stderr) as bar:
        for spec, m in models.items():
            results[spec] = curve(m, sizes, cfg.replicates, cfg.seed, cfg.n_boot, lambda: bar.update(1))
    for spec, rows in results.items():
        _print(spec, rows)
    chosen = choose(results)
    _print_choice(chosen)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {
        "config": asdict(cfg),
        "target": TARGET,
        "alpha": ALPHA,
        "population_of_paper_claims": PAPER_POPULATION,
        "metric": "ln steps",
        "chosen": chosen,
        "tables": results,
    }
    (out / "power.json").write_text(json.dumps(record, indent=1) + "\n")
    figure(results, out / "power.png")
    print(f"wrote {out / 'power.json'}, {out / 'power.png'}")
    return 0
