"""The path marks (`common/pathtrace.py`): free when off, and when on they list the project's own files only."""

from __future__ import annotations

import numpy as np

import common.pathtrace as pathtrace
from common.agents.explorer import RowConstants, to_integers
from common.pathtrace import ENV, files_of, read_traces, traced


def uses_the_core(mask):
    """mask's true entries' indices, through the project's own functions."""
    rows = mask.nonzero()[0]
    if not mask.any():  # another branch: other functions run
        RowConstants(lambda rows: (rows,))(rows)
    return rows + to_integers(np.zeros(len(rows)), rows + 1)  # (draws of 0: adds zeros)


def test_off_the_mark_is_the_function_itself(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    monkeypatch.setattr(pathtrace, "_log", None)
    assert traced("x")(uses_the_core) is uses_the_core


def test_on_each_call_lists_the_project_files_it_ran(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV, str(tmp_path))
    monkeypatch.setattr(pathtrace, "_log", None)
    monkeypatch.setattr(pathtrace, "MAX_CALLS", 2)
    marked = traced("unit")(uses_the_core)
    for mask in ([False, True], [True, False], [False, False], [False, False]):  # the 2nd repeats, the 4th is past
        assert list(marked(np.array(mask))) == list(np.flatnonzero(mask))
    outer = traced("outer")(lambda mask: marked(mask))  # a mark inside a mark: the outer one records
    outer(np.array([True]))
    calls = read_traces(tmp_path)
    assert [(c["label"], c["call"]) for c in calls] == [("unit", 0), ("unit", 2), ("outer", 0)]  # (a repeat: unwritten)
    assert files_of(calls[2]["functions"]) == {"common/agents/explorer.py"}
    # numpy's own files and this test file ran too, and are not the project's; the marks' wrapper is not listed
    assert files_of(calls[0]["functions"]) == {"common/agents/explorer.py"}
    assert calls[0]["functions"] == ["common/agents/explorer.py:to_integers"]
    assert "common/agents/explorer.py:RowConstants.__call__" in calls[1]["functions"]
