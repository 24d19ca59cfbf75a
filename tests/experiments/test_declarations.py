"""The declarations by id: 25 November's unchanged for its committed results, 28 November's (issue 34) as declared,
the registry picking the declaration a run recorded, and the settlement table of two runs."""

import hashlib
import json
import shutil

import numpy as np

from experiments import claims as first, claims_2026_11_28 as confirm, reproduce as rep
from experiments.__main__ import main
from experiments.conditions import BY_NAME, DELAY_CONDITIONS, FULL
from experiments.declarations import CONFIRM, DECLARATIONS, FIRST, NEWEST, get, missing_layouts, of_run
from experiments.evaluate import evaluate_claims
from experiments.report_claims import verdict_table
from experiments.report_runs import settlement, settlement_lines, write_settlement
from tests.experiments.test_claims import paper_levels, world
from tests.experiments.test_reproduce import TINY

FIRST_CLAIMS_SHA256 = "54c6e1d874010cb26bd626e35134e70c16fcf85d91cc7549378ecbf6171a02d3"
"""sha256 of repr(experiments.claims.CLAIMS) as declared on 25 November (at 93b5cd7): its committed results are
decided by exactly these tests."""


def by_id(claims):
    return {c.cid: c for c in claims}


def arms_of(t):
    return {(cond, arm.partition("@")[0]) for e in t.effects for _, cond, arm in e.terms}


def test_the_first_declarations_claims_are_unchanged():
    assert hashlib.sha256(repr(first.CLAIMS).encode()).hexdigest() == FIRST_CLAIMS_SHA256
    assert FIRST.claims is first.CLAIMS and FIRST.deciding == ("ln steps", "return") and FIRST.runs == (FULL,)


def test_the_registry_knows_both_and_runs_the_newest():
    assert set(DECLARATIONS) == {"2026-11-25", "2026-11-28"} and NEWEST == "2026-11-28" and get() is CONFIRM
    assert of_run({}) is FIRST  # a run from before declarations were versioned
    assert of_run({"declaration": "2026-11-28"}) is CONFIRM and of_run({"declaration": "2026-11-25"}) is FIRST


def test_only_ln_steps_decides_under_the_new_declaration():
    """Fewer steps but less return (DQN+RS stuck in a failed episode in four): the old declaration says mixed, the
    new one reproduced, with the return computed and shown."""
    assert CONFIRM.deciding == ("ln steps",) and set(CONFIRM.metrics) == {"ln steps", "return"}
    data = world(paper_levels)
    data["maze-high-nodelay"]["dqn-rs"].returns[:, ::4] = -10.0
    old, new = evaluate_claims(data, 300, FIRST)["C1"], evaluate_claims(data, 300, CONFIRM)["C1"]
    assert old["verdict"] == "mixed"
    assert new["metrics"]["return"]["verdict"] == "not reproduced" and new["verdict"] == "reproduced"
    for c in evaluate_claims(world(paper_levels, seed=2), 300, CONFIRM).values():
        assert c["verdict"] == c["metrics"]["ln steps"]["verdict"] != "mixed"


def test_the_paper_claims_are_decided_on_every_layout_pooled():
    new, old = by_id(confirm.CLAIMS), by_id(first.CLAIMS)
    for cid in ("C1", "C2", "C3", "C4", "C5", "C6"):
        assert new[cid].primary.layouts == "pooled" and new[cid].family == "paper"
        assert new[cid].primary.effects == old[cid].primary.effects  # the same tests, on the paper's population
    out = evaluate_claims(world(paper_levels), 300, CONFIRM)["C6"]
    assert out["layouts"] == "pooled" and out["metrics"]["ln steps"]["clusters"] == 8
    assert set(out["extension"]["populations"]) == {"honest", "misleading"} and out["extension"]["interaction"]


def test_m1_tests_the_reliability_against_the_papers_dqn_tamer():
    m1 = by_id(confirm.CLAIMS)["M1"].primary
    assert m1.kind == "greater" and m1.layouts == "misleading" and len(m1.effects) == 1
    assert m1.effects[0].terms == (
        (1.0, "maze-high-delay", "dqn-tamer"),
        (-1.0, "maze-high-delay", "dqn-tamer/trusted"),
    )
    assert by_id(confirm.CLAIMS)["A1"] == by_id(first.CLAIMS)["A1"]


def test_the_delay_claims_use_the_papers_uniform_prior_and_the_true_lags():
    claims = by_id(confirm.CLAIMS)
    for cid, algo, other in (
        ("D1", "deep-tamer", "uniform2"),
        ("D2", "dqn-tamer", "uniform2"),
        ("D3", "deep-tamer", "true"),
    ):
        c = claims[cid]
        assert arms_of(c.primary) == {(d, f"{algo}/{arm}") for d in DELAY_CONDITIONS for arm in ("learned", other)}
        observers = {cond for t in c.secondary for cond, _ in arms_of(t)}
        assert observers == set(DELAY_CONDITIONS)  # every observer's effect is shown
    for c in confirm.CLAIMS:
        for t in (c.primary,) + c.secondary:
            assert not {arm for _, arm in arms_of(t)} & set(CONFIRM.not_run)
            for cond, arm in arms_of(t):
                assert arm in next(x for x in CONFIRM.conditions([BY_NAME[cond]])).arms
    from experiments.arms import agent_for

    assert agent_for("dqn-tamer/uniform2").assumed_delay_probs[:3] == (1 / 3,) * 3
    assert sum(agent_for("dqn-tamer/uniform2").assumed_delay_probs[3:]) == 0
    assert agent_for("dqn-tamer/uniform").assumed_delay_probs == (1 / 7,) * 7  # 25 November's arm as it was


def test_the_declared_runs_are_fresh_and_sized_by_the_power_analysis():
    r1, r2 = confirm.RUNS
    assert (r1.layouts, r1.reps, r1.delay_layouts, r1.taxi_trials) == (480, 2, 128, 64) and r1.taxi_trials >= 32
    assert (r1.first_layout, r1.seed_block, r2.first_layout, r2.seed_block) == (180, 4, 660, 5)
    assert r2.__dict__ | {"first_layout": 0, "seed_block": 0} == r1.__dict__ | {"first_layout": 0, "seed_block": 0}
    assert confirm.EXPECTED_UNSETTLED == ("C1", "A1") and CONFIRM.scale(2) is r2
    assert missing_layouts(FULL) is None
    assert missing_layouts(r1) is None and missing_layouts(r2) is None  # the generator has 0-1139 since 28 Nov


def test_a_run_the_generator_cannot_supply_is_refused():
    from dataclasses import replace

    why = missing_layouts(replace(confirm.RUN_2, first_layout=900))
    assert why is not None and "900-1379" in why and "0-1139" in why


def test_expected_unsettled_claims_are_marked():
    out = evaluate_claims(world(paper_levels), 300, CONFIRM)
    assert out["C1"]["expected_unsettled"] and out["A1"]["expected_unsettled"] and "expected_unsettled" not in out["C2"]
    assert "expected unsettled" in "\n".join(verdict_table(out, "paper", {}, CONFIRM.deciding))
    assert not any("expected_unsettled" in c for c in evaluate_claims(world(paper_levels), 300, FIRST).values())


def test_report_from_a_table_decides_under_the_declaration_its_run_recorded(tmp_path):
    run = tmp_path / "run"
    rep.reproduce([BY_NAME["maze-high-delay"]], TINY, str(run), workers=1, progress=False, n_boot=50)
    timing = json.loads((run / "timing.json").read_text())
    new = json.loads((run / "claims.json").read_text())
    assert timing["declaration"] == "2026-11-28" and timing["replicate"] is None and new["declaration"] == "2026-11-28"
    assert new["claims"]["M1"]["primary_test"] == by_id(confirm.CLAIMS)["M1"].primary.text
    old_run = tmp_path / "old"
    old_run.mkdir()
    shutil.copy(run / "trials.csv.xz", old_run)
    del timing["declaration"]  # a table from before declarations were versioned
    (old_run / "timing.json").write_text(json.dumps(timing))
    out = tmp_path / "out"
    assert main(["report", "--from", str(old_run / "trials.csv.xz"), "--out", str(out), "--n-boot", "50"]) == 0
    old = json.loads((out / "claims.json").read_text())
    assert "declaration" not in old and old["claims"]["M1"]["primary_test"] == by_id(first.CLAIMS)["M1"].primary.text
    assert "the declaration of 2026-11-28" in (run / "REPORT.md").read_text()
    assert "return (shown, never decides)" in (run / "REPORT.md").read_text()


def _claims(verdicts: dict) -> dict:
    return {"declaration": "2026-11-28", "claims": {cid: {"verdict": v} for cid, v in verdicts.items()}}


def test_claims_settle_only_where_the_two_runs_agree(tmp_path):
    one = _claims({"C1": "inconclusive", "C2": "reproduced", "D1": "not reproduced", "M1": "not evaluated"})
    two = _claims({"C1": "reproduced", "C2": "reproduced", "D1": "not reproduced", "M1": "not evaluated"})
    rows = {r["claim"]: r for r in settlement(one, two)}
    assert [cid for cid, r in rows.items() if r["settled"]] == ["C2", "D1"]
    assert (rows["C1"]["run_1"], rows["C1"]["run_2"], rows["C1"]["expected_unsettled"]) == (
        "inconclusive",
        "reproduced",
        True,
    )
    lines = settlement_lines(list(rows.values()))
    assert (
        "| C2 | reproduced | reproduced | yes: reproduced |" in lines
        and "| M1 | not evaluated | not evaluated | no |" in lines
    )
    (tmp_path / "1.json").write_text(json.dumps(one))
    (tmp_path / "2.json").write_text(json.dumps(two))
    assert main(["settle", str(tmp_path / "1.json"), str(tmp_path / "2.json"), "--out", str(tmp_path / "s.md")]) == 0
    assert "| C1 (expected unsettled" in (tmp_path / "s.md").read_text()
    mixed = {"claims": {"C1": {"verdict": "mixed"}}}  # a run of the first declaration: nothing to settle against
    try:
        write_settlement(str(tmp_path / "1.json"), str(tmp_path / "1.json"), str(tmp_path / "x.md"))
        settlement(one, mixed)
    except ValueError as exc:
        assert "different declarations" in str(exc)
    else:
        raise AssertionError("runs of two declarations settled")
    assert np.all([r["settled"] for r in settlement(one, one) if r["run_1"] != "not evaluated"])
