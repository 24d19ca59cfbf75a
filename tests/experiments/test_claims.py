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


def test_the_metrics_decide_together_and_disagreement_is_mixed():
    """Fewer steps but less return (DQN+RS stuck more often in 1000-step episodes): ln steps says
    reproduced, return says not: C1 is mixed, never reproduced."""
    data = world(paper_levels)
    rs = data["maze-high-nodelay"]["dqn-rs"]
    rs.returns[:, ::4] = -10.0  # a failed episode in four
    out = evaluate_claims(data, n_boot=300)
    assert out["C1"]["metrics"]["ln steps"]["verdict"] == "reproduced"
    assert out["C1"]["metrics"]["return"]["verdict"] == "not reproduced"
    assert out["C1"]["verdict"] == "mixed"


def test_honest_layouts_decide_and_the_interaction_is_reported():
    """An effect on honest layouts only: the paper's claim (honest) is reproduced, the extension shows
    nothing on misleading layouts and a clear layout-class x method interaction."""

    def levels(cond, arm):
        return paper_levels(cond, arm)

    data = world(levels)
    dqn = data["maze-flip"]["dqn"]
    tamer = data["maze-flip"]["dqn-tamer"]
    mis = np.array([L % 2 == 1 for L in tamer.layouts])
    tamer.steps[mis], tamer.returns[mis] = dqn.steps[mis], dqn.returns[mis]
    out = evaluate_claims(data, n_boot=300)["C6"]
    assert out["layouts"] == "honest" and out["verdict"] == "reproduced"
    assert out["extension"]["populations"]["misleading"]["ln steps"]["estimate"] == 0.0
    inter = out["extension"]["interaction"]["ln steps"][0]
    assert inter["difference"] > 0.5 and inter["p_two_sided"] < 0.01


def test_c5_spans_the_maze_the_pomdp_and_taxi():
    conds = {cond for e in next(c for c in C.CLAIMS if c.cid == "C5").primary.effects for _, cond, _ in e.terms}
    assert conds == {"maze-stop", "pomdp-stop", "taxi-stop"}


def test_every_claim_declares_one_primary_test_and_a_family():
    assert [c.cid for c in C.CLAIMS] == ["C1", "C2", "C3", "C4", "C5", "C6", "D1", "D2", "D3", "A1", "M1"]
    for c in C.CLAIMS:
        assert isinstance(c.primary, C.Test) and c.family in C.FAMILIES
        for t in (c.primary,) + c.secondary:
            for e in t.effects:
                for _, cond, arm in e.terms:
                    assert cond in BY_NAME and arm.partition("@")[0] in BY_NAME[cond].arms


def test_a_world_as_the_paper_says_reproduces_the_claims():
    out = evaluate_claims(world(paper_levels), n_boot=300)
    for cid in ("C1", "C2", "C3", "C4", "C5", "C6", "D1", "D2", "D3", "A1", "M1"):
        assert out[cid]["verdict"] == "reproduced", (cid, out[cid]["metrics"])
        for metric in C.METRICS:
            assert out[cid]["metrics"][metric]["p_holm"] >= out[cid]["metrics"][metric]["p"]
    assert all(isinstance(c["fragile"], bool) for c in out.values())


def test_a_world_without_effects_reproduces_nothing():
    out = evaluate_claims(world(lambda cond, arm: 3.5, seed=1), n_boot=300)
    for cid, c in out.items():
        if C.CLAIMS[[x.cid for x in C.CLAIMS].index(cid)].primary.kind == "greater":
            assert c["verdict"] != "reproduced", cid
            assert all(r["verdict"] != "reproduced" for r in c["metrics"].values()), cid


def test_trials_are_clustered_by_layout_and_split_by_kind():
    data = world(paper_levels)
    t = C.CLAIMS[0].primary
    pooled, honest, misleading = (run_test(data, t, s, n_boot=200) for s in ("pooled", "honest", "misleading"))
    assert pooled["clusters"] == 8 and honest["clusters"] == 4 and misleading["clusters"] == 4
    assert pooled["trials"] == honest["trials"] + misleading["trials"]
