"""`python -m services.console compare` resumes: a finished run is kept and skipped when the command runs again,
keyed by design, pair, arm and the code's commit; a dirty tree is keyed apart from its commit; a design that names
its commit refuses any other checkout. Each run here is a real process standing in for the scripted session (a
few lines of Python that write the result a session writes), in a scratch git repository for the commit."""

import json
import subprocess
import sys

import pytest

from services.console import compare
from services.console.design import checkout_key, code_key, design_from_dict

FAKE_SESSION = """
import json, pathlib, sys
result, layout, log = pathlib.Path(sys.argv[1]), int(sys.argv[2]), pathlib.Path(sys.argv[3])
with log.open("a") as fh:
    fh.write(result.stem + "\\n")
if layout == 99:
    sys.exit(3)
goals = [True] * 15 if "dqn-tamer" in result.stem else [False] * (layout % 5) + [True] * (15 - layout % 5)
result.write_text(json.dumps({"runs": [{"steps_per_episode": [20] * 15, "total_steps": 300,
                                        "first_good_episode": 1, "reached_goal": goals}]}))
"""


@pytest.fixture
def repo(tmp_path):
    root = tmp_path / "code"
    root.mkdir()
    for args in (["init", "-q"], ["config", "user.email", "t@t"], ["config", "user.name", "t"]):
        subprocess.run(["git", "-C", str(root), *args], check=True)
    (root / "credit.py").write_text("DELAY = 1\n")
    subprocess.run(["git", "-C", str(root), "add", "."], check=True)
    subprocess.run(["git", "-C", str(root), "commit", "-qm", "code"], check=True)
    subprocess.run(["git", "-C", str(root), "tag", "frozen"], check=True)
    return root


@pytest.fixture
def launches(tmp_path, monkeypatch):
    """The runs started, in order: each fake session appends its tag to this log."""
    log = tmp_path / "launched.log"

    def command(design, arm, person, layout, seed, base, tag, timeout):
        return [sys.executable, "-c", FAKE_SESSION, str(base / "results" / f"{tag}.json"), str(layout), str(log)]

    monkeypatch.setattr(compare, "scripted_command", command)
    return lambda: log.read_text().split() if log.exists() else []


def small_design(**change):
    return design_from_dict(
        {
            "name": "tiny",
            "pairs": [[0, 300], [2, 301], [4, 302]],
            "episodes": 15,
            "measure": "goals",
            "primary": ["D", "T"],
            "arms": [{"name": "T", "algo": "dqn-tamer"}, {"name": "D", "algo": "dqn"}],
            **change,
        }
    )


def test_a_second_stretch_skips_every_finished_run_and_a_stopped_one_is_made_again(tmp_path, repo, launches, capfd):
    cfg = compare.CompareConfig(out=str(tmp_path / "out"), parallel=2)
    design = small_design()
    assert compare.run_design(cfg, design, repo) == 0
    assert len(launches()) == 6 and len(set(launches())) == 6
    first = capfd.readouterr().err
    assert "0 of 6 runs done, 6 remain" in first and "no run finished yet" in first
    key, dirty = code_key(repo)
    assert not dirty and (tmp_path / "out" / "tiny" / key / "compare.json").exists()

    assert compare.run_design(cfg, design, repo) == 0  # everything kept: nothing runs
    assert len(launches()) == 6
    assert "6 of 6 runs done, 0 remain" in capfd.readouterr().err

    # a stretch stopped in the middle of a run: its result may be there, its finished record is not
    stopped = compare.Run(design.arms[1], None, 2, 301)
    (tmp_path / "out" / "tiny" / key / "results" / f"{stopped.tag}.done.json").unlink()
    assert compare.run_design(cfg, design, repo) == 0
    assert launches()[6:] == [stopped.tag]
    err = capfd.readouterr().err
    assert "5 of 6 runs done, 1 remain" in err and "median run" in err
    verdict = json.loads((tmp_path / "out" / "tiny" / key / "compare.json").read_text())
    assert len(verdict["runs"]) == 6 and verdict["primary"]["differences"] == [0, 2, 4]


def test_a_failed_run_is_reported_and_the_others_are_kept(tmp_path, repo, launches, capfd):
    cfg = compare.CompareConfig(out=str(tmp_path / "out"), parallel=1)
    design = small_design(pairs=[[0, 300], [99, 301]])
    assert compare.run_design(cfg, design, repo) == 1
    assert "2 runs failed; the 2 others are kept" in capfd.readouterr().err
    assert compare.run_design(cfg, design, repo) == 1
    assert sorted(launches()[4:]) == sorted(t for t in launches()[:4] if "-l99-" in t)  # only the failed ones again


def test_a_dirty_tree_is_keyed_apart_from_its_commit(tmp_path, repo, launches, capfd):
    cfg = compare.CompareConfig(out=str(tmp_path / "out"), parallel=2)
    clean, _ = code_key(repo)
    assert compare.run_design(cfg, small_design(), repo) == 0
    (repo / "credit.py").write_text("DELAY = 2\n")
    dirty, is_dirty = code_key(repo)
    assert is_dirty and dirty.startswith(clean + "-dirty-")
    assert compare.run_design(cfg, small_design(), repo) == 0
    assert len(launches()) == 12  # none of the commit's runs passes for the changed code
    assert "uncommitted changes" in capfd.readouterr().err
    (repo / "notes.txt").write_text("an untracked file is a change too\n")
    assert code_key(repo)[0] not in (clean, dirty)


def test_a_design_that_names_its_commit_refuses_another_checkout_and_a_dirty_tree(tmp_path, repo, launches, capfd):
    cfg = compare.CompareConfig(out=str(tmp_path / "out"), parallel=2)
    assert checkout_key(small_design(commit="frozen"), repo) == code_key(repo)[0]
    with pytest.raises(ValueError, match="does not have"):
        checkout_key(small_design(commit="v9-never-tagged"), repo)
    (repo / "credit.py").write_text("DELAY = 2\n")
    with pytest.raises(ValueError, match="uncommitted changes"):
        checkout_key(small_design(commit="frozen"), repo)
    subprocess.run(["git", "-C", str(repo), "commit", "-qam", "credit changed"], check=True)
    assert compare.run_design(cfg, small_design(commit="frozen"), repo) == 2
    assert "runs on commit frozen" in capfd.readouterr().err and launches() == []
