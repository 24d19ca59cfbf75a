"""common/config.py as the command line of every command: a renamed or misspelt flag names its new spelling,
settings of several words add up, a bool flag alone means true, and subcommands (groups too) parse their config."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.config import Command, option, parse_config, run_commands, suggest
from experiments.__main__ import main as experiments_main
from experiments.run_config import RunConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    "argv, hint",
    [
        (["--p-feedback", "0.2"], "did you mean --observer.p-feedback?"),  # the flat flag before configs nested
        (["--p-feedback=0.2"], "did you mean --observer.p-feedback?"),
        (["--delay-probs", "1,0,0"], "--observer.delay-probs"),
        (["--observer.p-feedbak", "0.2"], "did you mean --observer.p-feedback?"),  # a typo: the closest spelling
        (["--zzz-qqq", "1e-3"], ""),  # nothing near: no guess
    ],
)
def test_an_unknown_flag_names_its_new_spelling(argv, hint, capsys):
    with pytest.raises(SystemExit) as exc:
        parse_config(RunConfig, argv, prog="run")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"unknown setting {argv[0].split('=')[0]}" in err
    assert hint in err
    if not hint:
        assert "did you mean" not in err


def test_a_subcommand_names_the_new_spelling_too(capsys):
    with pytest.raises(SystemExit) as exc:
        experiments_main(["run", "--p-feedback", "0.2", "--out", "/nonexistent/never-written"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "python -m experiments run: error: unknown setting --p-feedback; did you mean "
        "--observer.p-feedback? (see --help)"
    )


def test_a_config_file_with_an_old_flat_setting_names_the_nested_one(tmp_path, capsys):
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"p_feedback": 0.2}))
    with pytest.raises(SystemExit):
        parse_config(RunConfig, ["--config", str(path)], prog="run")
    assert "unknown setting 'p_feedback'; did you mean observer.p_feedback?" in capsys.readouterr().err


def test_suggest_prefers_the_same_leaf_over_a_close_spelling():
    known = ["--observer.p-feedback", "--observer.p-flip", "--agent.lr"]
    assert suggest("--p-feedback", known) == "; did you mean --observer.p-feedback?"
    assert suggest("--p-flips", known) == "; did you mean --observer.p-flip?"
    assert suggest("--zzz", known) == ""


@dataclass(frozen=True)
class Tool:
    """A tool of the test."""

    words: tuple[str, ...] = option(("a",), "several words", nargs="+")
    loud: bool = option(False, "a bool flag")
    path: str = option("", "where", positional=True)
    source: str = option("", "a field whose flag is a keyword", flag="from")


def test_several_words_add_up_a_bool_alone_is_true_and_groups_dispatch():
    seen: list = []

    def tool(config: Tool) -> int:
        seen.append(config)
        return 0

    def inner(config: Tool) -> int:
        seen.append(("inner", config))
        return 3

    commands = {"tool": Command(Tool, tool), "group": {"": "a group", "inner": Command(Tool, inner)}}
    assert run_commands("prog", "doc", commands, ["tool", "P", "--words", "x", "y", "--words", "z", "--loud"]) == 0
    assert seen[-1] == Tool(words=("x", "y", "z"), loud=True, path="P")
    assert run_commands("prog", "doc", commands, ["tool", "P", "--loud", "false", "--from", "T"]) == 0
    assert seen[-1] == Tool(words=("a",), loud=False, path="P", source="T")
    assert run_commands("prog", "doc", commands, ["group", "inner", "Q"]) == 3
    assert seen[-1] == ("inner", Tool(path="Q"))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["services", "up", "--p-feedback", "0.1"], "did you mean --observer.p-feedback?"),
        (["services", "security", "init", "DIR", "--no-perception"], "did you mean --perception?"),
        (["services", "bench-compare"], "moved: python -m experiments bench-compare --what live"),  # one, there
    ],
)
def test_the_services_command_line_names_new_spellings(argv, message):
    done = subprocess.run([sys.executable, "-m", *argv], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and message in done.stderr, done.stderr
