"""The console comparison's declared test (`services.console.compare`): paired episodes-to-goal differences, an
agent that never reached the goal scored episodes + 1, the Wilcoxon verdict."""
import pytest

from services.console import compare


def rows(dqn: list, tamer: list) -> list[dict]:
    pairs = compare.DESIGNS['first'].pairs
    out = []
    for (layout, seed), d, t in zip(pairs, dqn, tamer):
        out += [{"arm": "DQN", "layout": layout, "seed": seed, "first_good_episode": d},
                {"arm": "DQN-TAMER", "layout": layout, "seed": seed, "first_good_episode": t}]
    return out


def test_primary_test_scores_never_as_one_past_the_last_episode_and_decides_by_wilcoxon():
    clear = compare.primary_test(rows([None, 9, 8, 10, 7, 9, 6, 8], [2, 3, 2, 4, 3, 2, 3, 2]), compare.DESIGNS['first'])
    assert clear["differences"][0] == 11 - 2 and clear["wins"] == 8 and clear["verdict"] == "fewer episodes"
    assert clear["wilcoxon_p"] == pytest.approx(1 / 256)
    mixed = compare.primary_test(rows([3, 4, None, 8, 2, 5, 6, 7], [4, 3, None, None, 2, 6, 5, 7]), compare.DESIGNS['first'])
    assert (mixed["wins"], mixed["ties"], mixed["losses"]) == (2, 3, 3) and mixed["verdict"] == "not shown"


def test_goals_measure_counts_episodes_to_the_tenth_goal_and_decides_at_alpha_over_the_looks():
    design = compare.DESIGNS['goals']
    early = {"reached_goal": [True] * 15, "first_good_episode": 1}
    late = {"reached_goal": [False, False, False] + [True] * 12, "first_good_episode": 5}
    short = {"reached_goal": [True, False] * 7 + [True], "first_good_episode": 1}  # 8 goals: 15 + 2 missing
    assert compare.episodes_to_goal(early, design) == 10
    assert compare.episodes_to_goal(late, design) == 13
    assert compare.episodes_to_goal(short, design) == 17
    rows = []
    for (layout, seed), dqn in zip(design.pairs, [late] * 5 + [early] * 7):
        rows += [{"arm": "DQN", "layout": layout, "seed": seed, **dqn},
                 {"arm": design.primary[1], "layout": layout, "seed": seed, **early}]
    test = compare.primary_test(rows, design)
    # 5 wins and 7 ties: Wilcoxon p = 1/32 = 0.031 < 0.05, but the fourth look decides at 0.0125
    assert test["wilcoxon_p"] == pytest.approx(1 / 32) and test["alpha"] == pytest.approx(0.0125)
    assert test["verdict"] == "not shown"


def test_every_design_runs_pairs_no_earlier_design_or_pilot_used_and_counts_its_look():
    """A design's pairs are new (their seeds never used by an earlier design, nor by the in-process pilot's 9000+),
    and its verdict is taken at 0.05 over the number of designs tested so far."""
    from experiments.taxi_pilot import PILOT_SEED0

    seen: set[int] = set()
    for look, (name, design) in enumerate(compare.DESIGNS.items(), 1):
        seeds = {s for _, s in design.pairs}
        assert not seeds & seen, name
        assert max(seeds) < PILOT_SEED0
        assert design.looks in (1, look), name  # the first three were declared before looks were counted
        seen |= seeds
    onset = compare.DESIGNS["onset"]
    assert onset.looks == 5 and onset.arms[0].screen_credit == "onset" and onset.primary[0] == "DQN"
    assert compare.DESIGNS["replicate"].looks == 6 and len(compare.DESIGNS["replicate"].pairs) == 18
