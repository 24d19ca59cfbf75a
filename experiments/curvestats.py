"""Learning-curve statistics over trials (the sweeps' tables; the reproduction's verdicts are in
experiments/claims.py and experiments/evaluate.py).

Per-trial metrics:
  auc       mean return over all episodes (the area under the learning curve divided by its length)
  final     mean return over the last 10% of episodes (at least 5)
  initial   mean return over the first 10 episodes
  post_stop mean return over the last 10 episodes minus the mean over the 10 before feedback stopped
Curve metric:
  to90      first episode (numbered from 1) at which the 5-episode moving average of the trimmed-mean
            curve reaches 90% of the way from the start level to the best level (length + 1 when never)
Aggregation: 10%-trimmed mean across trials. Intervals: 95% percentile bootstrap over trials.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

TRIM = 0.1
N_BOOT = 2000
CI_LEVEL = 0.95
NEGLIGIBLE = 0.02
EQUIVALENCE = 0.05
BOOT_SEED = 20190128
SMOOTH = 5

REPRODUCED, NOT_REPRODUCED, INCONCLUSIVE, NOT_EVALUATED = (
    "reproduced",
    "not reproduced",
    "inconclusive",
    "not evaluated",
)
AGENT_NAMES = {"dqn": "DQN", "dqn-rs": "DQN+RS", "deep-tamer": "Deep TAMER", "dqn-tamer": "DQN-TAMER"}

Returns = dict[str, dict[str, np.ndarray]]  # condition -> agent -> [trials, episodes]


def tmean(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """Trimmed mean cutting int(TRIM * n) values at each end (as scipy.stats.trim_mean), vectorised:
    the trial axis is moved last and sorted, which is much faster than scipy's partition along a middle
    axis of the bootstrap arrays."""
    x = np.ascontiguousarray(np.moveaxis(np.asarray(x, np.float64), axis, -1))
    n = x.shape[-1]
    cut = int(TRIM * n)
    return np.sort(x, axis=-1)[..., cut : n - cut].mean(axis=-1)


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
    return R[:, -10:].mean(axis=1) - R[:, max(0, stop - 10) : stop].mean(axis=1)


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
