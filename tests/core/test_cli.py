import csv
import json
import subprocess
import sys

import pytest

from experiments.__main__ import main


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--observer.delay-probs", "0.3,0.3"], "delay-probs must sum to 1"),
        (["--agent.assumed-delay-probs", "0.5,0.6"], "assumed-delay-probs must sum to 1"),
        (["--env", "pong"], "unknown env 'pong'"),
        (["--env", "NoSuchWorld-v3"], "unknown env 'NoSuchWorld-v3'"),
        (["--env", "no_such_module:make"], "env factory 'no_such_module:make': cannot import 'no_such_module'"),
        (["--env", "json:no_such_factory"], "env factory 'json:no_such_factory': 'json' has no 'no_such_factory'"),
        (["--teacher-rule", "json:nope"], "teacher rule 'json:nope'"),
        (["--agent.no-such-field", "1"], "unknown setting --agent.no-such-field"),
        (["--p-feedback", "0.2"], "unknown setting --p-feedback"),
        (["--agent.lr", "-1"], "agent: lr must be positive"),
        (["--episodes", "-3"], "episodes must be >= 0"),
        (["--observer.p-feedback", "2"], "p-feedback must be in [0, 1]"),
        (["--layout", "5000"], "layout must be in 0..1139"),
        (["--seed", "x"], "--seed expects int"),
        (["--step-seconds", "0"], "step-seconds must be positive"),
        (["--observer.delay-s", "nosuch:1"], "unknown distribution 'nosuch'"),
    ],
)
def test_bad_arguments_give_one_line_error_naming_them(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", *argv, "--out", "/nonexistent/never-written"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_run_writes_config_and_episodes(tmp_path):
    out = tmp_path / "r"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments",
            "run",
            "--env",
            "maze",
            "--algo",
            "dqn-tamer",
            "--layout",
            "1",
            "--seed",
            "2",
            "--episodes",
            "3",
            "--observer.p-feedback",
            "0.5",
            "--observer.delay-probs",
            "0.3,0.6,0.1",
            "--agent.assumed-delay-probs",
            "0.3333,0.3333,0.3334",
            "--observer.stop-episode",
            "2",
            "--observer.p-flip",
            "0.1",
            "--agent.lr",
            "5e-4",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    config = json.loads((out / "config.json").read_text())
    assert config["task"]["layout"] == 1 and config["observer"]["p_flip"] == 0.1
    assert config["agent"]["lr"] == 5e-4 and config["agent"]["algo"] == "dqn-tamer"
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert [r["episode"] for r in rows] == ["0", "1", "2"]
    assert {"episode", "return", "steps", "feedback_given", "feedback_credited"} <= set(rows[0])
    assert int(rows[2]["feedback_given"]) <= 2  # the observer stopped after episode 1 (stragglers only)
    assert (out / "curve.png").stat().st_size > 1000
    delay = json.loads((out / "summary.json").read_text())["delay"]["observer"]
    credited = sum(int(r["feedback_credited"]) for r in rows)
    assert delay == {"median_s": 0.5, "p10_s": 0.0, "p90_s": 1.0, "feedbacks": credited, "learned": False}


def test_run_learns_a_delay_in_seconds_and_reports_it(tmp_path):
    out = tmp_path / "learned"
    assert (
        main(
            [
                "run",
                "--episodes",
                "3",
                "--seed",
                "1",
                "--agent.learn-delay",
                "true",
                "--observer.delay-s",
                "gamma:4,0,0.25",
                "--step-seconds",
                "0.5",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    delay = json.loads((out / "summary.json").read_text())["delay"]["observer"]
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert delay["feedbacks"] == sum(int(r["feedback_given"]) for r in rows) > 50
    assert 0 < delay["p10_s"] < delay["median_s"] < delay["p90_s"] <= 6 and delay["median_s"] != 2.1
    assert float(rows[-1]["delay_median_s"]) == pytest.approx(delay["median_s"], abs=1e-4)


def test_run_takes_a_gymnasium_id(tmp_path):
    out = tmp_path / "lake"
    assert main(["run", "--env", "FrozenLake-v1", "--episodes", "3", "--agent.lr", "5e-4", "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())  # the first record: the whole config tree
    assert config["task"]["env"] == "FrozenLake-v1" and config["agent"]["lr"] == 5e-4
    assert len(list(csv.DictReader((out / "episodes.csv").open()))) == 3


def test_run_takes_a_users_env_factory_and_rule(tmp_path, monkeypatch):
    (tmp_path / "userworld.py").write_text(
        "import gymnasium as gym\n"
        "CALLS = []\n"
        "def make_lake(layout=0):\n"
        "    return gym.make('FrozenLake-v1', is_slippery=False)\n"
        "def always_good(info):\n"
        "    CALLS.append(dict(info))\n"
        "    return 1\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib
    import sys as _sys

    _sys.modules.pop("userworld", None)
    userworld = importlib.import_module("userworld")
    out = tmp_path / "user"
    assert (
        main(
            [
                "run",
                "--env",
                "userworld:make_lake",
                "--teacher-rule",
                "userworld:always_good",
                "--episodes",
                "2",
                "--observer.p-feedback",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    steps = sum(int(r["steps"]) for r in rows)
    assert len(userworld.CALLS) == steps  # the user's rule judged every step ...
    assert {"reward", "target_distance_before", "target_distance_after"} <= set(userworld.CALLS[0])  # ... from info


def test_config_file_is_the_nested_tree_and_flags_override_it(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("env: FrozenLake-v1\nagent:\n  lr: 0.002\n  gamma: 0.8\nobserver:\n  p_feedback: 0.3\n")
    out = tmp_path / "r"
    assert main(["run", "--config", str(cfg), "--agent.lr", "5e-4", "--episodes", "1", "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())
    assert (
        config["task"]["env"],
        config["agent"]["lr"],
        config["agent"]["gamma"],
        config["observer"]["p_feedback"],
    ) == ("FrozenLake-v1", 5e-4, 0.8, 0.3)


@pytest.mark.parametrize(
    "text, message",
    [
        ("agent:\n  learning_rate: 0.1\n", "unknown setting 'learning_rate'"),
        ("observer:\n  p_feedback: 3\n", "p-feedback must be in [0, 1]"),
    ],
)
def test_bad_config_files_give_one_line_errors(tmp_path, capsys, text, message):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    with pytest.raises(SystemExit):
        main(["run", "--config", str(cfg), "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_a_missing_gpu_is_a_one_line_error(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: the error cannot happen")
    with pytest.raises(SystemExit):
        main(["run", "--env", "minigrid-empty", "--agent.device", "cuda", "--out", "/nonexistent/never"])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "device 'cuda': CUDA is not available" in err[0]
