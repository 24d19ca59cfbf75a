"""Measured evidence and computed verdicts for the paper's claims C1-C6 (DESIGN.md section 2).

Input: for each condition and agent, a returns matrix R[trial, episode]. Trial k is the same layout and
seed under every agent and condition, so every comparison is paired by trial.

Per-trial metrics:
  auc       mean return over all episodes (the area under the learning curve divided by its length)
  final     mean return over the last 10% of episodes (at least 5)
  initial   mean return over the first 10 episodes
  post_stop mean return over the last 10 episodes minus the mean over the 10 before feedback stopped
Curve metric:
  to90      first episode (numbered from 1) at which the 5-episode moving average of the trimmed-mean
            curve reaches 90% of the way from the condition's start level to its best level (length + 1
            when it never does: censored)

Aggregation: 10%-trimmed mean across trials (the paper's "trimmed mean of 30 runs"). Intervals: 95%
percentile bootstrap over trials, resampling trial indices jointly for all agents and conditions (paired).

Each claim is a set of sub-tests; each sub-test has a statistic (a difference of trimmed means) and a
kind. Margins are fractions of the condition's return scale: the best final level of any agent minus
the lowest first-episode level of any agent (what "learning" spans in that condition).
  greater      reproduced if the CI is above 0; not reproduced if it is below 0, or lies entirely
               within +-NEGLIGIBLE x scale (confidently no meaningful difference); else inconclusive
  equivalent   reproduced if the CI lies within +-EQUIVALENCE x scale; not reproduced if it lies
               entirely outside that band on one side; else inconclusive
  not_greater  reproduced if the CI's upper end is below EQUIVALENCE x scale; not reproduced if its lower
               end is above it; else inconclusive
A claim is reproduced if all its sub-tests are, not reproduced if any is not, inconclusive otherwise;
sub-tests whose conditions were not run are skipped ("not evaluated" if nothing is left).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

TRIM = 0.1
N_BOOT = 2000
CI_LEVEL = 0.95
NEGLIGIBLE = 0.02
EQUIVALENCE = 0.05
BOOT_SEED = 20190128
SMOOTH = 5

REPRODUCED, NOT_REPRODUCED, INCONCLUSIVE, NOT_EVALUATED = ("reproduced", "not reproduced", "inconclusive",
                                                           "not evaluated")
AGENT_NAMES = {"dqn": "DQN", "dqn-rs": "DQN+RS", "deep-tamer": "Deep TAMER", "dqn-tamer": "DQN-TAMER"}

Returns = dict[str, dict[str, np.ndarray]]  # condition -> agent -> [trials, episodes]


def tmean(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """Trimmed mean cutting int(TRIM * n) values at each end (as scipy.stats.trim_mean), vectorised:
    the trial axis is moved last and sorted, which is much faster than scipy's partition along a middle
    axis of the bootstrap arrays."""
    x = np.ascontiguousarray(np.moveaxis(np.asarray(x, np.float64), axis, -1))
    n = x.shape[-1]
    cut = int(TRIM * n)
    return np.sort(x, axis=-1)[..., cut:n - cut].mean(axis=-1)


# ------------------------------------------------------------------------------------- metrics
def auc(R: np.ndarray, stop: int | None = None) -> np.ndarray:
    return R.mean(axis=1)


def final(R: np.ndarray, stop: int | None = None) -> np.ndarray:
    w = max(5, R.shape[1] // 10)
    return R[:, -w:].mean(axis=1)


def initial(R: np.ndarray, stop: int | None = None) -> np.ndarray:
    return R[:, :10].mean(axis=1)


def post_stop(R: np.ndarray, stop: int | None) -> np.ndarray:
    if stop is None:
        raise ValueError("post_stop needs a feedback stop")
    return R[:, -10:].mean(axis=1) - R[:, max(0, stop - 10):stop].mean(axis=1)


METRICS: dict[str, Callable] = {"auc": auc, "final": final, "initial": initial}


def moving_average(y: np.ndarray, w: int = SMOOTH) -> np.ndarray:
    """Trailing moving average along the last axis (shorter window at the start)."""
    c = np.cumsum(y, axis=-1)
    out = c.copy()
    out[..., w:] = c[..., w:] - c[..., :-w]
    n = np.minimum(np.arange(1, y.shape[-1] + 1), w)
    return out / n


def episodes_to_level(curves: np.ndarray, level: float) -> np.ndarray:
    """First episode (numbered from 1) where the smoothed curve reaches `level` (curves [..., E]);
    E + 1 when it never does (censored)."""
    ma = moving_average(curves)
    hit = ma >= level
    return np.where(hit.any(axis=-1), hit.argmax(axis=-1) + 1, curves.shape[-1] + 1)


# ----------------------------------------------------------------------------------- bootstrap
def boot_indices(n: int, n_boot: int = N_BOOT, seed: int = BOOT_SEED) -> np.ndarray:
    """[n_boot + 1, n]: row 0 is the sample itself (the point estimate), then resamples."""
    rng = np.random.default_rng(seed)
    return np.vstack([np.arange(n)[None, :], rng.integers(0, n, size=(n_boot, n))])


def interval(values: np.ndarray) -> dict:
    """Point estimate (row 0) and percentile CI of the resampled rows."""
    a = (1 - CI_LEVEL) / 2
    lo, hi = np.quantile(values[1:], [a, 1 - a])
    return {"estimate": float(values[0]), "ci": [float(lo), float(hi)]}


def curve_band(R: np.ndarray, n_boot: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trimmed-mean curve and its bootstrap 95% band (per episode)."""
    idx = boot_indices(R.shape[0], n_boot)
    curves = np.concatenate([tmean(R[chunk], axis=1) for chunk in np.array_split(idx, max(1, len(idx) // 200))])
    a = (1 - CI_LEVEL) / 2
    lo, hi = np.quantile(curves[1:], [a, 1 - a], axis=0)
    return curves[0], lo, hi


# ---------------------------------------------------------------------------------- conditions
@dataclass
class CondData:
    name: str
    returns: dict[str, np.ndarray]  # agent -> [n, E]
    stop: int | None
    lo: float = 0.0
    hi: float = 1.0

    @property
    def scale(self) -> float:
        return max(self.hi - self.lo, 1e-9)


def condition_levels(returns: dict[str, np.ndarray]) -> tuple[float, float]:
    """(start level, best level): the lowest first-episode and the best final trimmed mean of any agent."""
    lo = min(float(tmean(R[:, 0])) for R in returns.values())
    hi = max(float(tmean(final(R))) for R in returns.values())
    return lo, hi


def condition_table(c: CondData, idx: np.ndarray) -> dict:
    """Per agent: auc, final, initial (and post_stop) with intervals, and episodes to 90%."""
    out = {}
    level = c.lo + 0.9 * (c.hi - c.lo)
    for agent, R in c.returns.items():
        row = {}
        metrics = dict(METRICS)
        if c.stop is not None:
            metrics["post_stop"] = post_stop
        for name, f in metrics.items():
            m = f(R, c.stop)
            row[name] = interval(tmean(m[idx], axis=1))
        curves = np.concatenate([tmean(R[chunk], axis=1) for chunk in np.array_split(idx, max(1, len(idx) // 200))])
        to90 = episodes_to_level(curves, level)
        row["to90"] = interval(to90.astype(float))
        row["to90"]["censored_at"] = R.shape[1] + 1
        out[agent] = row
    return out


# ------------------------------------------------------------------------------------ sub-tests
@dataclass
class SubTest:
    claim: str
    text: str
    kind: str  # greater | equivalent | not_greater
    needs: tuple[str, ...]  # conditions
    scale_of: str  # condition whose scale sets the margins
    stat: Callable[[dict[str, CondData], np.ndarray], np.ndarray]  # (conds, idx [b, n]) -> [b]


def _m(metric: str, cond: str, agent: str):
    def get(conds: dict[str, CondData], idx: np.ndarray) -> np.ndarray:
        c = conds[cond]
        f = post_stop if metric == "post_stop" else METRICS[metric]
        return tmean(f(c.returns[agent], c.stop)[idx], axis=1)
    return get


def _diff(a, b):
    return lambda conds, idx: a(conds, idx) - b(conds, idx)


def _did(a1, b1, a2, b2):
    return lambda conds, idx: (a1(conds, idx) - b1(conds, idx)) - (a2(conds, idx) - b2(conds, idx))


def build_subtests() -> list[SubTest]:
    N = AGENT_NAMES
    tests: list[SubTest] = []
    for freq in ("high", "low"):
        nd, d = f"maze-{freq}-nodelay", f"maze-{freq}-delay"
        tests.append(SubTest("C1", f"{freq} frequency, no delay: AUC(DQN+RS) - AUC(DQN) > 0", "greater", (nd,), nd,
                             _diff(_m("auc", nd, "dqn-rs"), _m("auc", nd, "dqn"))))
    for freq in ("high", "low"):
        nd, d = f"maze-{freq}-nodelay", f"maze-{freq}-delay"
        tests.append(SubTest("C2", f"{freq} frequency: delay degrades DQN+RS: AUC(no delay) - AUC(delay) > 0",
                             "greater", (nd, d), d, _diff(_m("auc", nd, "dqn-rs"), _m("auc", d, "dqn-rs"))))
        tests.append(SubTest("C2", f"{freq} frequency, with delay: AUC(DQN+RS) - AUC(DQN) about 0", "equivalent",
                             (d,), d, _diff(_m("auc", d, "dqn-rs"), _m("auc", d, "dqn"))))
    for delay in ("nodelay", "delay"):
        hi, lo = f"maze-high-{delay}", f"maze-low-{delay}"
        for agent in ("dqn-rs", "deep-tamer", "dqn-tamer"):
            tests.append(SubTest("C3", f"{'no delay' if delay == 'nodelay' else 'with delay'}: "
                                       f"AUC({N[agent]}, p=0.5) - AUC({N[agent]}, p=0.1) > 0", "greater",
                                 (hi, lo), lo, _diff(_m("auc", hi, agent), _m("auc", lo, agent))))
    for delay in ("nodelay", "delay"):
        lo = f"maze-low-{delay}"
        label = "no delay" if delay == "nodelay" else "with delay"
        for other in ("dqn", "dqn-rs", "dqn-tamer"):
            tests.append(SubTest("C4", f"p=0.1, {label}: AUC({N[other]}) - AUC(Deep TAMER) > 0 (Deep TAMER poorest)",
                                 "greater", (lo,), lo, _diff(_m("auc", lo, other), _m("auc", lo, "deep-tamer"))))
        for other in ("dqn", "dqn-rs", "deep-tamer"):
            tests.append(SubTest("C4", f"p=0.1, {label}: AUC(DQN-TAMER) - AUC({N[other]}) > 0 (DQN-TAMER best)",
                                 "greater", (lo,), lo, _diff(_m("auc", lo, "dqn-tamer"), _m("auc", lo, other))))
    for cond, label in (("maze-stop", "Maze MDP"), ("pomdp-stop", "Maze POMDP"), ("taxi-stop", "Taxi")):
        for other in ("dqn", "dqn-rs", "deep-tamer"):
            tests.append(SubTest("C5", f"{label}, feedback stops: AUC(DQN-TAMER) - AUC({N[other]}) > 0", "greater",
                                 (cond,), cond, _diff(_m("auc", cond, "dqn-tamer"), _m("auc", cond, other))))
        tests.append(SubTest("C5", f"{label}: Deep TAMER stagnates after the stop: return gain "
                                   f"(last 10 episodes - 10 before the stop) not above the margin", "not_greater",
                             (cond,), cond, _m("post_stop", cond, "deep-tamer")))
    tests.append(SubTest("C6", "15% flips: DQN-TAMER learns: final - initial return > 0", "greater",
                         ("maze-flip",), "maze-flip",
                         _diff(_m("final", "maze-flip", "dqn-tamer"), _m("initial", "maze-flip", "dqn-tamer"))))
    tests.append(SubTest("C6", "15% flips: AUC(DQN-TAMER) - AUC(DQN) > 0 (misread feedback still helps)",
                         "greater", ("maze-flip",), "maze-flip",
                         _diff(_m("auc", "maze-flip", "dqn-tamer"), _m("auc", "maze-flip", "dqn"))))
    return tests


CLAIMS = {
    "C1": "Without delay, DQN+RS learns faster than DQN (Maze).",
    "C2": "With delay, DQN+RS degrades and falls back to about DQN.",
    "C3": "More frequent feedback speeds every feedback-using method up.",
    "C4": "At low feedback frequency Deep TAMER is particularly poor; DQN-TAMER is the most robust.",
    "C5": "When feedback stops after 30 episodes, DQN-TAMER beats all others (Maze MDP, Maze POMDP, Taxi); "
          "Deep TAMER stagnates.",
    "C6": "With about 15% misread (flipped) feedback, DQN-TAMER still learns.",
}


def verdict_of(kind: str, ci: tuple[float, float], scale: float) -> str:
    lo, hi = ci
    if kind == "greater":
        m = NEGLIGIBLE * scale
        if lo > 0:
            return REPRODUCED
        if hi < 0 or (lo > -m and hi < m):
            return NOT_REPRODUCED
        return INCONCLUSIVE
    m = EQUIVALENCE * scale
    if kind == "equivalent":
        if lo > -m and hi < m:
            return REPRODUCED
        if lo > m or hi < -m:
            return NOT_REPRODUCED
        return INCONCLUSIVE
    if kind == "not_greater":
        if hi < m:
            return REPRODUCED
        if lo > m:
            return NOT_REPRODUCED
        return INCONCLUSIVE
    raise ValueError(f"unknown test kind {kind!r}")


def combine(verdicts: list[str]) -> str:
    if not verdicts:
        return NOT_EVALUATED
    if all(v == REPRODUCED for v in verdicts):
        return REPRODUCED
    if any(v == NOT_REPRODUCED for v in verdicts):
        return NOT_REPRODUCED
    return INCONCLUSIVE


def prepare(returns: Returns, stops: dict[str, int | None]) -> tuple[dict[str, CondData], int]:
    """Conditions with their levels, all cut to the smallest common number of trials."""
    n = min(R.shape[0] for agents in returns.values() for R in agents.values())
    conds = {}
    for name, agents in returns.items():
        cut = {a: np.asarray(R[:n], np.float64) for a, R in agents.items()}
        lo, hi = condition_levels(cut)
        conds[name] = CondData(name, cut, stops.get(name), lo, hi)
    return conds, n


def evaluate(returns: Returns, stops: dict[str, int | None], n_boot: int = N_BOOT) -> dict:
    """Everything claims.json holds: per-condition tables, sub-tests with intervals, claim verdicts."""
    conds, n = prepare(returns, stops)
    idx = boot_indices(n, n_boot)
    out = {"method": {"trim": TRIM, "n_boot": n_boot, "ci_level": CI_LEVEL, "negligible": NEGLIGIBLE,
                      "equivalence": EQUIVALENCE, "trials": n, "paired_by": "trial index (layout, seed)"},
           "conditions": {}, "subtests": [], "claims": {}}
    for name, c in conds.items():
        out["conditions"][name] = {"start_level": c.lo, "best_level": c.hi, "scale": c.scale, "stop": c.stop,
                                   "episodes": int(next(iter(c.returns.values())).shape[1]),
                                   "agents": condition_table(c, idx)}
    by_claim: dict[str, list[str]] = {k: [] for k in CLAIMS}
    for t in build_subtests():
        record = {"claim": t.claim, "test": t.text, "kind": t.kind, "conditions": list(t.needs)}
        if not all(cn in conds and all(a in conds[cn].returns for a in AGENT_NAMES) for cn in t.needs):
            record["verdict"] = NOT_EVALUATED
            out["subtests"].append(record)
            continue
        scale = conds[t.scale_of].scale
        iv = interval(t.stat(conds, idx))
        margin = (NEGLIGIBLE if t.kind == "greater" else EQUIVALENCE) * scale
        record.update(iv, margin=margin, verdict=verdict_of(t.kind, tuple(iv["ci"]), scale))
        by_claim[t.claim].append(record["verdict"])
        out["subtests"].append(record)
    for claim, text in CLAIMS.items():
        out["claims"][claim] = {"text": text, "verdict": combine(by_claim[claim]),
                                "subtests": [s for s in out["subtests"] if s["claim"] == claim]}
    return out
