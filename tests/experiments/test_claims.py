"""Verdict logic on synthetic learning curves whose truth is known."""
import numpy as np
import pytest

from experiments import claims as C

AGENTS = ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer")
CONDS = ("maze-high-nodelay", "maze-high-delay", "maze-low-nodelay", "maze-low-delay", "maze-stop",
         "pomdp-stop", "taxi-stop", "maze-flip")
STOPS = {"maze-stop": 30, "pomdp-stop": 30, "taxi-stop": 30}


def curve(rate, n=30, episodes=100, final=1.0, start=-3.0, noise=0.3, seed=0, stall_after=None):
    """Trials of an exponential learning curve; rate = fraction of the remaining gap closed per episode."""
    rng = np.random.default_rng(seed)
    e = np.arange(episodes)
    progress = 1 - (1 - rate) ** e
    if stall_after is not None:
        progress = np.where(e < stall_after, progress, progress[stall_after - 1])
    mean = start + (final - start) * progress
    return mean[None, :] + noise * rng.standard_normal((n, episodes))


def paper_world(seed=0, **overrides):
    """Curves shaped as the paper says they are."""
    rates = {
        "maze-high-nodelay": {"dqn": 0.05, "dqn-rs": 0.15, "deep-tamer": 0.2, "dqn-tamer": 0.3},
        "maze-high-delay": {"dqn": 0.05, "dqn-rs": 0.06, "deep-tamer": 0.15, "dqn-tamer": 0.25},
        "maze-low-nodelay": {"dqn": 0.05, "dqn-rs": 0.08, "deep-tamer": 0.02, "dqn-tamer": 0.12},
        "maze-low-delay": {"dqn": 0.05, "dqn-rs": 0.05, "deep-tamer": 0.015, "dqn-tamer": 0.1},
        "maze-stop": {"dqn": 0.05, "dqn-rs": 0.06, "deep-tamer": 0.15, "dqn-tamer": 0.25},
        "pomdp-stop": {"dqn": 0.05, "dqn-rs": 0.06, "deep-tamer": 0.15, "dqn-tamer": 0.25},
        "taxi-stop": {"dqn": 0.05, "dqn-rs": 0.06, "deep-tamer": 0.15, "dqn-tamer": 0.25},
        "maze-flip": {"dqn": 0.05, "dqn-rs": 0.05, "deep-tamer": 0.1, "dqn-tamer": 0.2},
    }
    rates.update(overrides)
    out = {}
    for ci, cond in enumerate(CONDS):
        out[cond] = {}
        for ai, agent in enumerate(AGENTS):
            stall = 30 if (agent == "deep-tamer" and cond in STOPS) else None
            # Deep TAMER stalls below the others' level once feedback stops.
            final = 0.3 if stall else 1.0
            out[cond][agent] = curve(rates[cond][agent], seed=seed * 100 + ci * 10 + ai, stall_after=stall, final=final)
    # DQN ignores feedback: the same trials in every Maze MDP condition.
    for cond in ("maze-high-delay", "maze-low-nodelay", "maze-low-delay", "maze-stop", "maze-flip"):
        out[cond]["dqn"] = out["maze-high-nodelay"]["dqn"]
    return out


def verdicts(returns):
    return {k: v["verdict"] for k, v in C.evaluate(returns, STOPS, n_boot=400)["claims"].items()}


def test_a_world_that_behaves_as_the_paper_says_reproduces_every_claim():
    assert verdicts(paper_world()) == {c: "reproduced" for c in C.CLAIMS}


def test_rs_no_better_than_dqn_without_delay_is_not_reproduced():
    world = paper_world()
    world["maze-high-nodelay"]["dqn-rs"] = world["maze-high-nodelay"]["dqn"] - 0.5  # clearly worse
    assert verdicts(world)["C1"] == "not reproduced"


def test_identical_curves_give_not_reproduced_for_a_greater_claim_not_inconclusive():
    world = paper_world()
    for cond in ("maze-high-nodelay", "maze-low-nodelay"):
        world[cond]["dqn-rs"] = world[cond]["dqn"].copy()
    v = C.evaluate(world, STOPS, n_boot=400)
    c1 = v["claims"]["C1"]["subtests"]
    assert all(s["ci"] == [0.0, 0.0] for s in c1) and v["claims"]["C1"]["verdict"] == "not reproduced"


def test_too_few_noisy_trials_are_inconclusive():
    world = {c: {a: R[:4] * 1.0 for a, R in agents.items()} for c, agents in paper_world().items()}
    for c in world:
        for a in AGENTS:
            world[c][a] = world[c][a] + np.random.default_rng(1).normal(0, 3, world[c][a].shape)
    v = verdicts(world)
    assert "inconclusive" in v.values()


def test_deep_tamer_that_keeps_improving_after_the_stop_does_not_stagnate():
    world = paper_world()
    world["maze-stop"]["deep-tamer"] = curve(0.03, seed=5)  # slow and still climbing at the end
    sub = [s for s in C.evaluate(world, STOPS, n_boot=400)["subtests"] if "Maze MDP: Deep TAMER stagnates" in s["test"]]
    assert sub[0]["verdict"] == "not reproduced"


def test_equivalence_needs_a_tight_interval():
    assert C.verdict_of("equivalent", (-0.01, 0.02), scale=1.0) == "reproduced"
    assert C.verdict_of("equivalent", (-0.2, 0.02), scale=1.0) == "inconclusive"
    assert C.verdict_of("equivalent", (0.1, 0.3), scale=1.0) == "not reproduced"
    assert C.verdict_of("greater", (0.001, 0.3), scale=1.0) == "reproduced"
    assert C.verdict_of("greater", (-0.01, 0.01), scale=1.0) == "not reproduced"
    assert C.verdict_of("greater", (-0.01, 0.5), scale=1.0) == "inconclusive"
    assert C.verdict_of("not_greater", (-0.5, 0.04), scale=1.0) == "reproduced"
    with pytest.raises(ValueError):
        C.verdict_of("bigger", (0, 1), 1.0)


def test_combining_sub_verdicts_and_missing_conditions():
    assert C.combine(["reproduced", "reproduced"]) == "reproduced"
    assert C.combine(["reproduced", "inconclusive"]) == "inconclusive"
    assert C.combine(["inconclusive", "not reproduced"]) == "not reproduced"
    assert C.combine([]) == "not evaluated"
    only = {k: v for k, v in paper_world().items() if k == "maze-flip"}
    v = verdicts(only)
    assert v["C6"] == "reproduced" and v["C1"] == "not evaluated"


def test_episodes_to_level_and_bands():
    y = np.concatenate([np.zeros(10), np.ones(10)])
    assert C.episodes_to_level(y, 0.9) == 15  # episode 15 (from 1): the 5th of the ones
    assert C.episodes_to_level(np.zeros(7), 0.5) == 8  # never: censored at length + 1
    R = curve(0.1, n=30)
    mid, lo, hi = C.curve_band(R, n_boot=200)
    assert np.all(lo <= mid + 1e-12) and np.all(mid <= hi + 1e-12)
    np.testing.assert_allclose(mid, C.tmean(R, axis=0))


def test_trimmed_mean_is_scipys():
    from scipy.stats import trim_mean
    x = np.random.default_rng(0).normal(size=(7, 30, 5))
    for axis in range(3):
        np.testing.assert_allclose(C.tmean(x, axis), trim_mean(x, 0.1, axis=axis))
