"""Sweeps: a grid from the command line and from YAML, the tidy table, cache resume, named contrasts."""

import csv
import json
import os

import numpy as np
import pyarrow.parquet as pq
import pytest

from experiments.__main__ import main
from experiments.conditions import trial_seed
from experiments.sweeps import analysis, execute
from experiments.sweeps.grid import Sweep, load_yaml
from experiments.sweeps.report import run_sweep

GRID = ["observer.p_feedback=0.1,0.5", "agent.algo=dqn,dqn-tamer"]
CONTRAST = "agent.algo=dqn-tamer - agent.algo=dqn"
YAML = """
name: small
trials: 3
layouts: [0, 1]
set:
  env.episodes: 3
grid:
  observer.p_feedback: [0.1, 0.5]
  agent.algo: [dqn, dqn-tamer]
contrasts:
  - agent.algo=dqn-tamer - agent.algo=dqn
"""


def cli(out, *extra):
    return main(
        [
            "sweep",
            "--grid",
            *GRID,
            "--trials",
            "3",
            "--layouts",
            "0,1",
            "--set",
            "env.episodes=3",
            "--contrast",
            CONTRAST,
            "--name",
            "small",
            "--out",
            str(out),
            "--workers",
            "1",
            "--no-progress",
            "--boot",
            "50",
            *extra,
        ]
    )


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_grid_from_the_command_line_gives_a_tidy_table_summary_figures_and_contrasts(tmp_path, capsys):
    assert cli(tmp_path) == 0
    rows = read_csv(tmp_path / "trials.csv")
    # one row per cell (2 x 2), trial (3) and episode (3), every swept field a column
    assert len(rows) == 4 * 3 * 3
    assert list(rows[0]) == [
        "cell",
        "observer.p_feedback",
        "agent.algo",
        "trial",
        "layout",
        "seed",
        "episode",
        "return",
        "steps",
        "feedback_given",
        "feedback_credited",
    ]
    assert {(r["observer.p_feedback"], r["agent.algo"]) for r in rows} == {
        ("0.1", "dqn"),
        ("0.1", "dqn-tamer"),
        ("0.5", "dqn"),
        ("0.5", "dqn-tamer"),
    }
    # trials cycle over the given layouts, the reproduction's seeds (from layout and repetition k // 2)
    assert {(r["trial"], r["layout"], r["seed"]) for r in rows} == {
        ("0", "0", str(trial_seed(0, 0))),
        ("1", "1", str(trial_seed(1, 0))),
        ("2", "0", str(trial_seed(0, 1))),
    }
    table = pq.read_table(tmp_path / "trials.parquet")
    assert table.num_rows == len(rows) and table.column_names == list(rows[0])
    assert table.schema.field("observer.p_feedback").type == "double"
    assert table.column("return").to_pylist() == [float(r["return"]) for r in rows]
    summary = read_csv(tmp_path / "summary.csv")
    assert len(summary) == 4 and {"ln_steps", "ln_steps_lo", "ln_steps_hi", "success", "return"} <= set(summary[0])
    assert sorted(p.name for p in tmp_path.glob("group-*.png")) == ["group-00.png", "group-01.png"]
    md = (tmp_path / "SWEEP.md").read_text()
    assert "observer.p_feedback=0.5" in md and "## Contrasts" in md
    out = capsys.readouterr().out
    assert "12 cell-trials" in out and CONTRAST in out


def test_named_contrast_is_computed_from_the_table(tmp_path):
    assert cli(tmp_path, "--contrast", "return: observer.p_feedback=0.5 - observer.p_feedback=0.1") == 0
    rows = read_csv(tmp_path / "trials.csv")
    result = json.loads((tmp_path / "contrasts.json").read_text())
    assert [(r["metric"], r["where"]) for r in result] == [
        ("ln_steps", "observer.p_feedback=0.1"),
        ("ln_steps", "observer.p_feedback=0.5"),
        ("return", "agent.algo=dqn"),
        ("return", "agent.algo=dqn-tamer"),
    ]

    def per_trial(column, transform, **where):  # per-trial mean over episodes, in trial order
        return np.array(
            [
                np.mean(
                    [
                        transform(float(r[column]))
                        for r in rows
                        if r["trial"] == str(k) and all(r[f] == v for f, v in where.items())
                    ]
                )
                for k in range(3)
            ]
        )

    for r, p in zip(result[:2], ("0.1", "0.5")):  # mean ln steps, dqn-tamer minus dqn, paired by trial
        a = per_trial("steps", np.log, **{"observer.p_feedback": p, "agent.algo": "dqn-tamer"})
        b = per_trial("steps", np.log, **{"observer.p_feedback": p, "agent.algo": "dqn"})
        assert r["estimate"] == pytest.approx(np.mean(a - b))
    dqn = {p: per_trial("return", float, **{"observer.p_feedback": p, "agent.algo": "dqn"}) for p in ("0.1", "0.5")}
    assert result[2]["estimate"] == pytest.approx(np.mean(dqn["0.5"] - dqn["0.1"])) == 0  # DQN ignores feedback
    assert result[2]["verdict"] == "no meaningful difference"
    for r in result:
        assert r["ci"][0] <= r["estimate"] <= r["ci"][1]
        assert r["verdict"] == analysis.decide(r["ci"], r["p_holm"], r["margin"], r["estimate"])
        assert r["p_holm"] >= r["p"] and r["trials"] == 3 and r["clusters"] == 2  # layouts 0 and 1
        assert r["underpowered"] == (r["trials_needed"] is None or r["trials_needed"] > 3)
    assert "underpowered" in (tmp_path / "SWEEP.md").read_text()


def test_the_same_grid_from_yaml_is_the_same_sweep(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text(YAML)
    assert cli(tmp_path / "cli") == 0
    assert (
        main(["sweep", str(path), "--out", str(tmp_path / "yaml"), "--workers", "1", "--no-progress", "--boot", "50"])
        == 0
    )
    assert Sweep(**load_yaml(str(path))).record() == Sweep(**load_yaml(str(tmp_path / "cli" / "sweep.yaml"))).record()
    for name in ("trials.csv", "summary.csv", "contrasts.json"):
        assert (tmp_path / "yaml" / name).read_text() == (tmp_path / "cli" / name).read_text()


class Stop(Exception):
    pass


def test_interrupted_sweep_resumes_and_a_repeated_one_only_replots(tmp_path, monkeypatch):
    sweep = Sweep(**{**load_yaml_text(tmp_path, YAML)})
    ref = run_sweep(sweep, str(tmp_path / "ref"), workers=1, progress=False, n_boot=50)
    out = str(tmp_path / "out")

    def interrupt(done, total):
        if done >= 4:
            raise Stop

    with pytest.raises(Stop):
        run_sweep(sweep, out, workers=1, progress=False, n_boot=50, on_trial=interrupt)
    left = execute.plan(execute.sweep_slots(sweep), execute.by_key(f"{out}/cache"))
    assert len(left.records) >= 4 and left.todo
    ran = []
    real = execute.run_trials
    monkeypatch.setattr(execute, "run_trials", lambda specs, **kw: ran.extend(specs) or real(specs, **kw))
    resumed = run_sweep(sweep, out, workers=1, progress=False, n_boot=50)
    assert sorted(execute.sweep_key(s) for s in ran) == sorted(t.key for t in left.todo)
    assert resumed.run.computed == len(left.todo) and resumed.run.cached == len(left.records)
    assert (tmp_path / "out" / "trials.csv").read_text() == (tmp_path / "ref" / "trials.csv").read_text()
    ran.clear()
    timing = json.loads((tmp_path / "out" / "timing.json").read_text())
    again = run_sweep(sweep, out, workers=1, progress=False, n_boot=50)
    assert ran == [] and again.run.computed == 0 and again.run.cached == 12
    after = json.loads((tmp_path / "out" / "timing.json").read_text())
    assert after["total_s"] == timing["total_s"] and after["replot_s"] > 0
    # DQN ignores feedback: its trials are shared by the two observer cells (9 distinct trials for 12 slots)
    assert ref.run.computed == 9 and ref.run.filled == 12


def load_yaml_text(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return load_yaml(str(p))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--grid", "observer.p_feedbak=0.1"], "unknown sweep field"),
        (["--grid", "observer.p_feedback=0.1,2"], "p-feedback must be in [0, 1]"),
        (["--grid", "agent.algo=dqn,sarsa"], "agent.algo must be one of"),
        (
            ["--grid", "agent.algo=dqn,dqn-tamer", "--contrast", "agent.algo=deep-tamer - agent.algo=dqn"],
            "not in the grid",
        ),
        (["--grid", "agent.algo=dqn,dqn-tamer", "--contrast", "agent.algo=dqn-tamer-agent.algo=dqn"], "a minus"),
        (["--grid", "agent.lr=fast"], "agent.lr expects float"),
        (["--set", "observer.delay_probs=[0.5,0.6]"], "must sum to 1"),
        (["--grid", "env.layout=3,5000"], "layout must be in 0..1139"),
        (["--set", "env=NoSuchEnv-v0"], "unknown env"),
    ],
)
def test_bad_sweeps_fail_with_one_line_before_running(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", *args, "--trials", "2", "--out", str(tmp_path), "--no-progress"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "cache").exists()


def test_any_agent_observer_and_env_field_reaches_the_trial():
    sweep = Sweep(
        grid={"agent.lr": [0.01], "observer.delay_probs": [(1.0, 0.0, 0.0)], "env.name": ["taxi"]},
        fixed={"agent.algo": "deep-tamer", "observer.stop_episode": 5, "env.episodes": 4},
        trials=2,
    )
    spec = sweep.spec(sweep.cells()[0], 1)
    assert (spec.agent.algo, spec.agent.lr, spec.agent.update_interval) == ("deep-tamer", 0.01, 4)  # taxi's default
    assert spec.observer.delay_probs == (1.0, 0.0, 0.0) and spec.observer.stop_episode == 5
    assert (spec.env, spec.episodes, spec.layout, spec.seed) == ("taxi", 4, 0, trial_seed(0, 1))


def test_the_sweep_file_in_the_docs_is_valid(tmp_path):
    doc = open(os.path.join(os.path.dirname(__file__), "..", "..", "docs", "sweeps.md")).read()
    text = doc.split("```yaml\n", 1)[1].split("```", 1)[0]
    sweep = Sweep(**load_yaml_text(tmp_path, text))
    assert len(sweep.cells()) == 8 and sweep.legend == "observer.p_flip"
    cons = [analysis.parse_contrast(c, sweep) for c in sweep.contrasts]
    assert [c.metric for c in cons] == ["ln_steps", "return"] and cons[1].left == {"observer.p_flip": 0.0}


def test_an_unreachable_ray_address_is_a_one_line_error(tmp_path, capsys):
    code = main(
        [
            "sweep",
            "--grid",
            "agent.algo=dqn,dqn-tamer",
            "--trials",
            "2",
            "--set",
            "episodes=2",
            "--out",
            str(tmp_path),
            "--no-progress",
            "--ray",
            "127.0.0.1:1",
        ]
    )
    assert code == 1
    assert capsys.readouterr().err.strip() == "error: cannot connect to Ray at 127.0.0.1:1: Connection refused"


def test_a_sweep_trial_is_the_reproductions_trial():
    from dataclasses import replace

    from experiments.conditions import BY_NAME, FULL, trial_spec

    cond = BY_NAME["maze-high-delay"]
    FULL = replace(FULL, first_layout=0, seed_block=1)  # a sweep runs the development layouts and seeds
    sweep = Sweep(
        grid={"agent.algo": ["dqn", "dqn-tamer"]},
        trials=45,
        fixed={"observer.p_feedback": 0.5, "observer.delay_probs": (0.3, 0.6, 0.1), "episodes": cond.episodes(FULL)},
    )
    for cell in sweep.cells():
        for k in (0, 7, 44):
            mine, theirs = sweep.spec(cell, k), trial_spec(cond, cell.values["agent.algo"], k, FULL)
            assert mine == theirs and execute.sweep_key(mine) == execute.trial_key(theirs)
