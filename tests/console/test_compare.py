"""The console comparison's declared test (`services.console.compare`): paired episodes-to-goal differences, an
agent that never reached the goal scored episodes + 1, the Wilcoxon verdict."""

import dataclasses

import numpy as np
import pytest

from services.console import compare, compare_tests


def rows(dqn: list, tamer: list) -> list[dict]:
    pairs = compare.DESIGNS["first"].pairs
    out = []
    for (layout, seed), d, t in zip(pairs, dqn, tamer):
        out += [
            {"arm": "DQN", "layout": layout, "seed": seed, "first_good_episode": d},
            {"arm": "DQN-TAMER", "layout": layout, "seed": seed, "first_good_episode": t},
        ]
    return out


def test_primary_test_scores_never_as_one_past_the_last_episode_and_decides_by_wilcoxon():
    clear = compare_tests.primary_test(
        rows([None, 9, 8, 10, 7, 9, 6, 8], [2, 3, 2, 4, 3, 2, 3, 2]), compare.DESIGNS["first"]
    )
    assert clear["differences"][0] == 11 - 2 and clear["wins"] == 8 and clear["verdict"] == "fewer episodes"
    assert clear["wilcoxon_p"] == pytest.approx(1 / 256)
    mixed = compare_tests.primary_test(
        rows([3, 4, None, 8, 2, 5, 6, 7], [4, 3, None, None, 2, 6, 5, 7]), compare.DESIGNS["first"]
    )
    assert (mixed["wins"], mixed["ties"], mixed["losses"]) == (2, 3, 3) and mixed["verdict"] == "not shown"


def test_goals_measure_counts_episodes_to_the_tenth_goal_and_decides_at_alpha_over_the_looks():
    design = compare.DESIGNS["goals"]
    early = {"reached_goal": [True] * 15, "first_good_episode": 1}
    late = {"reached_goal": [False, False, False] + [True] * 12, "first_good_episode": 5}
    short = {"reached_goal": [True, False] * 7 + [True], "first_good_episode": 1}  # 8 goals: 15 + 2 missing
    assert compare_tests.episodes_to_goal(early, design) == 10
    assert compare_tests.episodes_to_goal(late, design) == 13
    assert compare_tests.episodes_to_goal(short, design) == 17
    rows = []
    for (layout, seed), dqn in zip(design.pairs, [late] * 5 + [early] * 7):
        rows += [
            {"arm": "DQN", "layout": layout, "seed": seed, **dqn},
            {"arm": design.primary[1], "layout": layout, "seed": seed, **early},
        ]
    test = compare_tests.primary_test(rows, design)
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


def test_holm_steps_down_and_stops_at_the_first_test_that_fails():
    # p sorted: 0.001 (< 0.05/4), 0.01 (< 0.05/3), 0.03 (> 0.05/2: stops), 0.04 (never reached)
    assert compare_tests.holm([0.03, 0.001, 0.04, 0.01], 0.05) == pytest.approx([0.025, 0.0125, 0.0, 0.05 / 3])
    assert compare_tests.holm([0.5], 0.05) == [0.05]


def test_a_holm_design_tests_each_person_on_each_layout_kind(tmp_path):
    from services.console.design import design_from_dict

    design = design_from_dict(
        {
            "name": "t",
            "pairs": [[0, 200], [2, 201], [4, 202], [6, 203], [1, 204], [3, 205]],
            "arms": [{"name": "T", "algo": "dqn-tamer", "screen_delay": "learned"}, {"name": "D", "algo": "dqn"}],
            "primary": ["D", "T"],
            "episodes": 15,
            "measure": "goals",
            "multiplicity": "holm",
            "people": {"slow": "uniform:1,2", "drifting": "drift:0.5,2,0.2"},
        }
    )
    assert design.tests() == [
        ("slow", "honest"),
        ("slow", "misleading"),
        ("drifting", "honest"),
        ("drifting", "misleading"),
    ]
    early = {"reached_goal": [True] * 15, "first_good_episode": 1, "total_steps": 300}
    late = {"reached_goal": [False] * 5 + [True] * 10, "first_good_episode": 6, "total_steps": 900}
    rows = []
    for person in design.people:
        for layout, seed in design.pairs:
            dqn = late if person == "slow" and layout % 2 == 0 else early
            rows += [
                {"arm": "D", "person": person, "layout": layout, "seed": seed, **dqn},
                {"arm": "T", "person": person, "layout": layout, "seed": seed, **early},
            ]
    tests = compare_tests.declared_tests(rows, design)
    slow_honest = tests[0]
    assert slow_honest["wins"] == 4 and slow_honest["wilcoxon_p"] == pytest.approx(1 / 16)
    assert slow_honest["alpha"] == pytest.approx(0.05 / 4) and slow_honest["verdict"] == "not shown"
    assert all(t["wilcoxon_p"] == 1.0 for t in tests[1:])
    assert "| slow | 0 | 200 |" in compare.table(rows, design)
    pooled = compare_tests.declared_tests(rows, dataclasses.replace(design, tests_by="person"))
    assert [(t["person"], t["kind"]) for t in pooled] == [("slow", None), ("drifting", None)]
    assert pooled[0]["wins"] == 4 and pooled[0]["ties"] == 2 and pooled[0]["alpha"] == pytest.approx(0.025)
    assert len(compare_tests.secondary_tests(rows, dataclasses.replace(design, tests_by="person"))) == 4


@pytest.mark.parametrize(
    "change, message",
    [
        ({"colour": "red"}, "unknown fields"),
        ({"primary": ["D", "X"]}, "primary"),
        ({"people": {"p": "drift:1"}}, "drift"),
        ({"pairs": [[0, 1], [0, 1]]}, "distinct"),
        ({"pairs": [[5000, 1]]}, "layouts"),
        ({"multiplicity": "holm"}, "holm tests one hypothesis per declared person"),
    ],
)
def test_a_design_file_that_says_something_wrong_is_refused(change, message):
    from services.console.design import design_from_dict

    raw = {
        "name": "t",
        "pairs": [[0, 1]],
        "arms": [{"name": "T", "algo": "dqn-tamer"}, {"name": "D", "algo": "dqn"}],
        "primary": ["D", "T"],
        **change,
    }
    with pytest.raises(ValueError, match=message):
        design_from_dict(raw)


def test_the_unknown_teacher_design_is_declared_as_issue_24_asks():
    """Three people the learner is not told about (one drifting 0.5 -> 2 s, one long-tailed lognormal, one bimodal),
    the learned delay against DQN by the episode of the tenth goal, honest and misleading layouts, Holm."""
    from common.envs.maze import layout_kind
    from services.console.lags import lag_plan

    d = compare.DESIGNS["unknown-teacher"]
    assert list(compare.DESIGNS)[-1] == "unknown-teacher"
    assert d.multiplicity == "holm" and d.tests_by == "person" and d.alpha == 0.05
    assert d.measure == "goals" and d.goals == 10 and d.primary == ("DQN", "DQN-TAMER, learned delay")
    tamer = next(a for a in d.arms if a.name == d.primary[1])
    assert tamer.algo == "dqn-tamer" and tamer.screen_delay == "learned"
    assert {layout_kind(lay) for lay, _ in d.pairs} == {"honest", "misleading"}
    plans = {name: lag_plan(spec, d.episodes, d.episode_steps, 0) for name, spec in d.people.items()}
    drifting = np.median(plans["drifting"], axis=1)
    assert drifting[0] == pytest.approx(0.5, rel=0.1) and drifting[-1] == pytest.approx(2.0, rel=0.1)
    tail = plans["long-tailed"]
    assert np.percentile(tail, 99) > 3 * np.median(tail)  # long-tailed
    bimodal = np.histogram(plans["bimodal"], bins=np.arange(0, 3.01, 0.2))[0]
    assert bimodal[2:4].sum() > bimodal[5] and bimodal[8:10].sum() > bimodal[5]  # two modes, about 0.6 and 1.8 s


def test_every_declared_runs_command_is_one_the_scripted_person_takes(tmp_path):
    """The command compare starts for each arm and person of every design parses as `services.console scripted`
    flags (a design whose arm said `default` once passed the word itself, which scripted refused: no run started)."""
    from common.config import parse_config
    from services.console.scripted import ScriptedConfig

    for design in compare.DESIGNS.values():
        lay, seed = design.pairs[0]
        for arm in design.arms:
            for person in design.persons():
                cmd = compare.scripted_command(design, arm, person, lay, seed, tmp_path, "t", 60.0)
                assert cmd[1:4] == ["-m", "services.console", "scripted"]
                cfg = parse_config(ScriptedConfig, cmd[4:])
                assert (cfg.algo, cfg.layout, cfg.seed) == (arm.algo, lay, seed)
                if arm.screen_delay != "default":
                    assert cfg.learner.screen_delay == arm.screen_delay


def test_people_reports_a_run_whose_person_pressed_little_or_that_went_slow(tmp_path, capsys):
    """`python -m services.console people`: each finished run's pace and presses a step, read from its summary; a
    run whose person pressed at under half the design's rate, or slower than 3/4 of its pace, is reported with why."""
    import json

    from services.console import compare_people
    from services.console.service import cli

    design = compare.DESIGNS["unknown-teacher"]
    key = tmp_path / design.name / "abc123"
    people = {
        "fine": (400, 210.0, 200, 200, "ok"),  # 1.9 steps/s, 0.5 presses a step
        "quiet": (400, 210.0, 20, 20, "ok"),  # the page hardly pressed
        "lossy": (400, 210.0, 90, 60, "ok"),  # presses published and never logged
        "slow": (400, 400.0, 200, 200, "timeout"),
    }
    for tag, (steps, wall, published, logged, outcome) in people.items():
        (key / "runs" / tag).mkdir(parents=True)
        (key / "results").mkdir(exist_ok=True)
        (key / "results" / f"{tag}.done.json").write_text("{}")
        person = {"web-1": {"received": logged, "published": published, "logged": logged}}
        summary = {"steps_sent": steps, "wall_s": wall, "outcome": outcome, "people": person}
        (key / "runs" / tag / "summary.json").write_text(json.dumps(summary))
    assert cli(["people", "--design", design.name, "--out", str(tmp_path)]) == 0
    rows = json.loads((key / "people.json").read_text())["runs"]
    assert [t for t, r in rows.items() if r["reported"]] == ["lossy", "quiet", "slow"]
    assert rows["fine"]["pace"] == round(400 / 210, 3) and rows["fine"]["presses_per_step"] == 0.5
    assert "30 presses published and not logged" in rows["lossy"]["why"]
    assert "outcome timeout" in rows["slow"]["why"]
    printed = capsys.readouterr().out
    assert "4 finished runs" in printed and "3 runs reported" in printed
    assert compare_people.main(compare_people.PeopleConfig(design="unknown-teacher", out=str(tmp_path / "x"))) == 2
