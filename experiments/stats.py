"""Statistics for clustered trials: cluster bootstrap, one-sided tests on cluster means, Holm, MDE.

Trials are clustered by maze layout (several seeds of one layout share its difficulty), so every
interval resamples whole clusters and every test treats the cluster, not the trial, as the unit:
  cluster_means     per-cluster mean of a per-trial quantity
  cluster_bootstrap percentile interval of the mean over clusters, clusters drawn with replacement
                    (each resample weights a cluster by its trial count, as resampling layouts does)
  one_sided_p       scipy.stats.ttest_1samp on the cluster means, alternative "greater" (and, for
                    the fragility check, scipy.stats.wilcoxon on the same means)
  holm              Holm's step-down adjustment of a family of p-values
  mde               the smallest true effect the design detects with 80% power at the adjusted level
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

BOOT_SEED = 20190128


def cluster_means(values: np.ndarray, clusters: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cluster ids, per-cluster mean, per-cluster trial count) of per-trial `values` [n, ...]."""
    values = np.asarray(values, np.float64)
    ids, inverse, counts = np.unique(np.asarray(clusters), return_inverse=True, return_counts=True)
    sums = np.zeros((len(ids),) + values.shape[1:])
    np.add.at(sums, inverse, values)
    return ids, sums / counts.reshape((-1,) + (1,) * (values.ndim - 1)), counts


@lru_cache(maxsize=64)
def cluster_boot_weights(n_clusters: int, n_boot: int, seed: int = BOOT_SEED) -> np.ndarray:
    """[n_boot, n_clusters]: how many times each cluster is drawn in each resample (read-only: cached)."""
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_clusters, size=(n_boot, n_clusters))
    w = np.zeros((n_boot, n_clusters))
    np.add.at(w, (np.repeat(np.arange(n_boot), n_clusters), draws.ravel()), 1.0)
    w.flags.writeable = False
    return w


def cluster_bootstrap(
    values: np.ndarray, clusters: np.ndarray, n_boot: int = 2000, level: float = 0.95, seed: int = BOOT_SEED
) -> dict:
    """Mean of per-trial `values` [n] with a percentile interval resampling whole clusters.

    Returns estimate, ci, se (the resamples' standard deviation) and the resampled means."""
    _, means, counts = cluster_means(values, clusters)
    w = cluster_boot_weights(len(means), n_boot, seed) * counts[None, :]
    boot = (w @ means) / w.sum(axis=1)
    a = (1 - level) / 2
    lo, hi = np.quantile(boot, [a, 1 - a])
    estimate = float(np.sum(means * counts) / counts.sum())
    return {"estimate": estimate, "ci": [float(lo), float(hi)], "se": float(boot.std(ddof=1)), "boot": boot}


def one_sided_p(cluster_values: np.ndarray, test: str = "t") -> float:
    """p-value of H0: mean <= 0 against H1: mean > 0 over cluster-level values (t or wilcoxon)."""
    from scipy import stats as sps  # (here: scipy.stats takes a second to import; the CLI's parsing needs none)

    x = np.asarray(cluster_values, np.float64)
    if len(x) < 2 or np.allclose(x, x[0]):
        return 0.0 if len(x) and x[0] > 0 else 1.0
    if test == "t":
        return float(sps.ttest_1samp(x, 0.0, alternative="greater").pvalue)
    if test == "wilcoxon":
        if np.all(x == 0):
            return 1.0
        return float(sps.wilcoxon(x, alternative="greater").pvalue)
    raise ValueError(f"unknown test {test!r}")


def holm(pvalues: dict[str, float]) -> dict[str, float]:
    """Holm's step-down adjusted p-values (monotone, capped at 1); reject where adjusted p < alpha."""
    order = sorted(pvalues, key=lambda k: pvalues[k])
    m = len(order)
    adjusted, running = {}, 0.0
    for i, key in enumerate(order):
        running = max(running, min(1.0, (m - i) * pvalues[key]))
        adjusted[key] = running
    return adjusted


def mde(se: float, alpha: float, power: float = 0.8) -> float:
    """Smallest true effect a one-sided level-alpha test with this standard error detects with `power`."""
    from scipy import stats as sps

    return float((sps.norm.ppf(1 - alpha) + sps.norm.ppf(power)) * se)


def fmt_p(p: float) -> str:
    return "<0.0001" if p < 1e-4 else f"{p:.4f}"


def log_steps(steps: np.ndarray) -> np.ndarray:
    """Natural log of steps per episode (the primary metric's per-episode value)."""
    return np.log(np.maximum(np.asarray(steps, np.float64), 1.0))


def nan_to(x: float, default: float = math.nan) -> float:
    return default if x is None or not math.isfinite(x) else float(x)
