"""The declared claims and their evaluation on synthetic trials whose truth is known."""
import numpy as np

from experiments import claims as C
from experiments.conditions import BY_NAME, QUICK, cluster_of, n_trials, trial_layout
from experiments.evaluate import ArmData, evaluate_claims, run_test

E = 40


def world(levels, seed=0, layout_sd=0.5, noise=0.3):
    """Data for every condition the claims use: ln steps = level(cond, arm) + layout effect + noise.
    `levels(cond, arm)` gives the arm's mean ln steps in that condition."""
    rng = np.random.default_rng(seed)
    layout_effect = rng.normal(0, layout_sd, 100)
    data = {}
    for name, cond in BY_NAME.items():
        n = n_trials(cond, QUICK)
        lay = np.array([trial_layout(cond, QUICK, k)[0] for k in range(n)])
        cl = np.array([cluster_of(cond, QUICK, k) for k in range(n)])
        data[name] = {}
        for arm in cond.arms:
            ln = levels(name, arm) + layout_effect[cl][:, None] + noise * rng.standard_normal((n, E))
            steps = np.clip(np.round(np.exp(ln)), 1, 1000)
            data[name][arm] = ArmData(steps, 1 - 0.01 * steps, lay, cl, cond.stop_episode, cond.is_taxi)
    return data


def paper_levels(cond, arm):
    """As the paper says: feedback helps, more at high frequency; delay hurts DQN+RS; Deep TAMER is poor at
    low frequency; DQN-TAMER is best and most robust; learned lags beat uniform ones."""
    base = {"dqn": 4.0, "dqn-rs": 3.4, "deep-tamer": 3.3, "dqn-tamer": 3.0}
    algo, _, how = arm.partition("/")
    level = base.get(algo, 3.0)
    if "low" in cond:
        level += {"dqn": 0.0, "dqn-rs": 0.4, "deep-tamer": 1.0, "dqn-tamer": 0.2}[algo]
    if algo == "dqn-rs" and "-delay" in cond:
        level += 0.5
    if how == "uniform":
        level += 0.5
    if how == "adaptive":
        level -= 0.5
    return level


def test_every_claim_declares_one_primary_test_and_a_family():
    assert [c.cid for c in C.CLAIMS] == ["C1", "C2", "C3", "C4", "C5", "C6", "D1", "D2", "D3", "A1"]
    for c in C.CLAIMS:
        assert isinstance(c.primary, C.Test) and c.family in C.FAMILIES
        for t in (c.primary,) + c.secondary:
            for e in t.effects:
                for _, cond, arm in e.terms:
                    assert cond in BY_NAME and arm.partition("@")[0] in BY_NAME[cond].arms


def test_a_world_as_the_paper_says_reproduces_the_claims():
    out = evaluate_claims(world(paper_levels), n_boot=300)
    for cid in ("C1", "C2", "C3", "C4", "C5", "C6", "D1", "D2", "D3", "A1"):
        assert out[cid]["verdict"] == "reproduced", (cid, out[cid]["estimate"], out[cid]["p_holm"])
        assert out[cid]["p_holm"] >= out[cid]["p"]
    assert all(isinstance(c["fragile"], bool) for c in out.values())


def test_a_world_without_effects_reproduces_nothing():
    out = evaluate_claims(world(lambda cond, arm: 3.5, seed=1), n_boot=300)
    for cid, c in out.items():
        if C.CLAIMS[[x.cid for x in C.CLAIMS].index(cid)].primary.kind == "greater":
            assert c["verdict"] != "reproduced", cid


def test_trials_are_clustered_by_layout_and_split_by_kind():
    data = world(paper_levels)
    t = C.CLAIMS[0].primary
    pooled, honest, misleading = (run_test(data, t, s, n_boot=200) for s in ("pooled", "honest", "misleading"))
    assert pooled["clusters"] == 8 and honest["clusters"] == 4 and misleading["clusters"] == 4
    assert pooled["trials"] == honest["trials"] + misleading["trials"]
