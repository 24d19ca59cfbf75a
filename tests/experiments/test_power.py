"""The power analysis (`experiments/power.py`): two runs' agreement on a verdict, estimated by resampling clusters,
on synthetic claims whose answer is known."""

import numpy as np
import pytest

from experiments import power


def claim(values, margin=0.1, kind="greater", cid="C1", universe="maze") -> power.ClaimModel:
    """A claim of one effect with one trial per cluster."""
    v = np.asarray(values, float)
    comp = power.Component(universe, v[:, None], np.ones(len(v), int), np.ones(len(v), bool), margin)
    return power.ClaimModel(cid, "paper", kind, [comp])


def run(models, layouts, replicates=400, seed=0):
    return power.curve(models, [(layouts, 1)], replicates, seed, n_boot=200)[0]


def test_agreement_is_the_chance_that_two_replicates_say_the_same():
    assert power.agreement(["reproduced"] * 10) == 1.0
    assert power.agreement(["reproduced"] * 5 + ["inconclusive"] * 5) == pytest.approx(2 * 5 * 4 / (10 * 9))
    with pytest.raises(ValueError):
        power.agreement(["reproduced"])


def test_effects_far_from_every_threshold_always_agree():
    rng = np.random.default_rng(1)
    strong = claim(1.0 + 0.3 * rng.standard_normal(60), cid="C1")
    below = claim(-1.0 + 0.3 * rng.standard_normal(60), cid="C2")
    row = run([strong, below], 60, replicates=100)
    assert row["claims"]["C1"] == {"agreement": 1.0, "verdicts": {"reproduced": 100}}
    assert row["claims"]["C2"] == {"agreement": 1.0, "verdicts": {"not reproduced": 100}}


def test_a_null_effect_is_reproduced_at_the_test_level_so_two_runs_agree_about_0_905():
    """Mean exactly 0 and a margin no interval can fall below: each replicate is reproduced with probability
    alpha = 0.05 and inconclusive otherwise, so two runs agree with probability 0.95^2 + 0.05^2 = 0.905."""
    magnitudes = np.linspace(0.2, 2.0, 30)
    null = claim(np.concatenate([magnitudes, -magnitudes]), margin=-1e9)
    row = run([null], 60, replicates=600)
    share = row["claims"]["C1"]["verdicts"].get("reproduced", 0) / 600
    assert 0.025 < share < 0.08
    assert row["claims"]["C1"]["agreement"] == pytest.approx(0.905, abs=0.04)


def test_agreement_on_a_real_but_small_effect_grows_with_the_design():
    rng = np.random.default_rng(2)
    x = rng.standard_normal(60)
    small = claim(0.35 + (x - x.mean()) / x.std())  # mean 0.35, sd 1: decided at 400 layouts, not at 15
    rows = power.curve([small], [(15, 1), (400, 1)], 200, 3, n_boot=200)
    assert rows[0]["claims"]["C1"]["agreement"] < 0.8
    assert rows[1]["claims"]["C1"] == {"agreement": 1.0, "verdicts": {"reproduced": 200}}
    chosen = power.choose({"synthetic": rows})
    assert chosen["size"] == {"layouts": 400, "seeds": 1} and chosen["never_reached"] == []


def test_condition_sets_grow_in_proportion_and_seeds_are_drawn_within_a_layout():
    models = [
        claim(np.zeros(60), universe="maze"),
        claim(np.zeros(16), universe="delay", cid="D1"),
        claim(np.zeros(4), universe="taxi", cid="C5"),
    ]
    assert power.universe_sizes(models, 240, 2) == {"maze": (240, 2), "delay": (64, 2), "taxi": (32, 1)}
    picked, within = power._draw(5, 1000, 3, np.array([1, 2, 3, 1, 4]), np.random.default_rng(0))
    assert set(picked) == {0, 1, 2, 3, 4} and within.shape == (1000, 3)
    assert np.all(within < np.array([1, 2, 3, 1, 4])[picked, None]) and within.max() == 3
    assert power.parse_size("240x2") == (240, 2)
    with pytest.raises(ValueError, match="LAYOUTSxSEEDS"):
        power.parse_size("many")
