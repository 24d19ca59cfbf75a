"""Cluster bootstrap (a case with known layout variance), Holm's correction, one-sided tests, MDE."""

import numpy as np
import pytest

from experiments import stats


def clustered(k=40, m=5, sd_layout=1.0, sd_trial=0.2, seed=0):
    rng = np.random.default_rng(seed)
    layout_effect = rng.normal(0, sd_layout, k)
    clusters = np.repeat(np.arange(k), m)
    values = layout_effect[clusters] + rng.normal(0, sd_trial, k * m)
    return values, clusters


def test_cluster_bootstrap_se_matches_the_layout_variance():
    k, m, sd_l, sd_t = 40, 5, 1.0, 0.2
    ses, naive = [], []
    for seed in range(20):
        v, cl = clustered(k, m, sd_l, sd_t, seed)
        ses.append(stats.cluster_bootstrap(v, cl, n_boot=1000, seed=seed)["se"])
        naive.append(stats.cluster_bootstrap(v, np.arange(len(v)), n_boot=1000, seed=seed)["se"])
    expected = np.sqrt((sd_l**2 + sd_t**2 / m) / k)  # the mean of k cluster means
    assert np.mean(ses) == pytest.approx(expected, rel=0.15)
    # treating the 200 trials as independent understates it by about sqrt(m)
    assert np.mean(naive) < 0.6 * np.mean(ses)


def test_cluster_bootstrap_interval_covers_the_truth_at_about_95_percent():
    hits = 0
    for seed in range(100):
        v, cl = clustered(30, 3, 1.0, 0.3, seed)
        ci = stats.cluster_bootstrap(v, cl, n_boot=500, seed=seed)["ci"]
        hits += ci[0] <= 0.0 <= ci[1]
    assert 85 <= hits <= 100


def test_unequal_cluster_sizes_weight_clusters_by_their_trials():
    v = np.array([1.0, 1.0, 1.0, 4.0])
    cl = np.array([0, 0, 0, 1])
    b = stats.cluster_bootstrap(v, cl, n_boot=200)
    assert b["estimate"] == pytest.approx(7 / 4)
    assert min(b["boot"]) == pytest.approx(1.0) and max(b["boot"]) == pytest.approx(4.0)


def test_holm():
    adj = stats.holm({"a": 0.01, "b": 0.04, "c": 0.03, "d": 0.005})
    # sorted: d 0.005*4=0.02, a 0.01*3=0.03, c 0.03*2=0.06, b max(0.04*1, 0.06)=0.06
    assert adj == pytest.approx({"d": 0.02, "a": 0.03, "c": 0.06, "b": 0.06})
    assert stats.holm({"x": 0.7, "y": 0.9}) == pytest.approx({"x": 1.0, "y": 1.0})


def test_one_sided_p_and_mde():
    rng = np.random.default_rng(1)
    assert stats.one_sided_p(rng.normal(1.0, 1.0, 50)) < 1e-4
    assert stats.one_sided_p(rng.normal(-1.0, 1.0, 50)) > 0.99
    assert stats.one_sided_p(rng.normal(1.0, 1.0, 50), "wilcoxon") < 1e-4
    # MDE at alpha 0.05, 80% power: 2.486 standard errors
    assert stats.mde(0.1, 0.05) == pytest.approx(0.2486, abs=1e-3)
    # and a test at that effect rejects about 80% of the time
    se, k = 0.1, 30
    sd = se * np.sqrt(k)
    rejects = np.mean(
        [stats.one_sided_p(np.random.default_rng(s).normal(stats.mde(se, 0.05), sd, k)) < 0.05 for s in range(300)]
    )
    assert 0.7 < rejects < 0.9
