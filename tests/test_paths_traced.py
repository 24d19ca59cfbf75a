"""Paths are measured, not claimed (issue 31): the project files a step and a press pass through, traced in the
real processes, are the lists docs/architecture.md shows.

One short live run (`services up --teacher web`: actor, learner, recorder and console as processes over Zenoh on
loopback, a scripted person pressing in Chromium) with `HITL_TRACE` set: each service profiles its marked calls
(`common/pathtrace.py`) and writes the project functions each ran. A path is the union of its pieces; a piece is
what every traced call of its kind ran (the intersection), so a branch only some calls take (an episode's end,
a first press's new delay model) is not counted:

- a step: the actor's `step_and_publish` (env.step, the Step out), the learner's `take_input` of a Step that ran
  an update and published weights, and the actor's `next_action` that adopted those weights;
- a press: the console's `handle` of a feedback message (from the page's WebSocket), the learner's `take_input` of
  that Feedback credited at once (the H update), and the same `next_action`.

The test fails when the doc's generated block differs from the trace. To write the block again:
`UPDATE_PATHS=1 .venv/bin/python -m pytest -q -p no:randomly tests/test_paths_traced.py -n 0`.
"""

from __future__ import annotations

import os
import re

import pytest

from common.pathtrace import ENV, files_of, read_traces
from tests.console.harness import WebRun, scripted_person
from tests.services.live import ROOT

pytestmark = [pytest.mark.live, pytest.mark.browser]

DOC = ROOT / "docs" / "architecture.md"
BEGIN = "<!-- traced paths: written by tests/test_paths_traced.py, do not edit by hand -->"
END = "<!-- end of traced paths -->"
RUN = "--env maze --layout 0 --algo dqn-tamer --episodes 50 --episode-steps 30 --max-steps 60 --rate 5 --seed 3"
TARGETS = {"step": 15, "press": 20}  # issue 31's targets, reported in the doc

# (label, functions every call of the piece must have run: "file:qualified name" suffixes)
UPDATED = ("FlatRMSProp.step_rows", "Learner.publish_weights")  # a gradient step, and the new weights sent
ADOPTED = ("actor.weights", ("WeightsFollower.offer", "StackedMLP.load_policy_state"))
ACTED = ("actor.act", ("Actor.next_action",))
PIECES = {
    "step": [
        ("actor.step", ("Actor.step_and_publish",)),
        ("learner.input", ("Learner.consume_step", *UPDATED)),
        ADOPTED,
        ACTED,
    ],
    "press": [
        ("console.page", ("PageInputs.feedback",)),
        ("learner.input", ("Learner.consume_feedback", "feedback_rounds", *UPDATED)),
        ADOPTED,
        ACTED,
    ],
}


def ran(functions: list[str], needed: tuple[str, ...]) -> bool:
    return all(any(f.endswith(n) for f in functions) for n in needed)


def piece_files(calls: list[dict], label: str, needed: tuple[str, ...]) -> set[str]:
    """The files every traced `label` call that ran all of `needed` passed through."""
    chosen = [files_of(c["functions"]) for c in calls if c["label"] == label and ran(c["functions"], needed)]
    assert chosen, f"no traced {label} call ran {needed}: the trace missed the path"
    return set.intersection(*chosen)


def traced_paths(calls: list[dict]) -> dict[str, dict[str, set[str]]]:
    """Each path's files, with the processes each ran in."""
    paths: dict[str, dict[str, set[str]]] = {}
    for name, pieces in PIECES.items():
        files: dict[str, set[str]] = {}
        for label, needed in pieces:
            for f in piece_files(calls, label, needed):
                files.setdefault(f, set()).add(label.split(".")[0])
        paths[name] = files
    return paths


def render(paths: dict[str, dict[str, set[str]]]) -> str:
    lines = [
        BEGIN,
        "",
        "Measured, not written by hand: `tests/test_paths_traced.py` traces a short live run and fails",
        "when this block differs. To write it again: `UPDATE_PATHS=1 .venv/bin/python -m pytest -q -p no:randomly",
        "tests/test_paths_traced.py -n 0`.",
        "",
    ]
    for name, files in paths.items():
        lines.append(f"A {name}: {len(files)} project files (target: {TARGETS[name]} or fewer).")
        lines.append("")
        lines += [f"- `{f}` ({', '.join(sorted(files[f]))})" for f in sorted(files)]
        lines.append("")
    return "\n".join([*lines, END])


def doc_block() -> str:
    text = DOC.read_text()
    m = re.search(re.escape(BEGIN) + ".*?" + re.escape(END), text, re.S)
    assert m, f"docs/architecture.md has no block between {BEGIN!r} and {END!r}"
    return m.group(0)


def test_the_doc_lists_the_files_a_step_and_a_press_pass_through(tmp_path, monkeypatch):
    traces = tmp_path / "traces"
    traces.mkdir()
    monkeypatch.setenv(ENV, str(traces))
    run = WebRun(tmp_path, "paths", *RUN.split())
    scripted_person(run, tmp_path / "profile", "{p: 0.8, lagMin: 0.3, lagMax: 0.8, seed: 5}")

    calls = read_traces(traces)
    assert {c["label"] for c in calls} == {"actor.act", "actor.step", "actor.weights", "learner.input", "console.page"}
    paths = traced_paths(calls)
    # What the trace must see for the comparison to mean anything: each path's ends, in its own process.
    assert {"actor"} <= paths["step"]["common/envs/maze.py"] and "learner" in paths["step"]["common/agents/networks.py"]
    assert paths["press"]["services/console/people.py"] == {"console"}  # (the page's press handler)
    assert "learner" in paths["press"]["common/agents/feedback.py"]
    assert not any(f.startswith("tests/") for p in paths.values() for f in p)
    block = render(paths)
    if os.environ.get("UPDATE_PATHS"):
        DOC.write_text(DOC.read_text().replace(doc_block(), block))
    assert doc_block() == block, "the traced paths differ from docs/architecture.md's:\n" + block
