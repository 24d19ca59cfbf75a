"""Test-session wiring for `make test` (`pytest -n 4 --dist loadgroup`).

Tests that share an expensive module- or session-scoped fixture (a converted face model and decoded clips, a
live run that several tests read) stay on one xdist worker, so the fixture is built once rather than on each
worker; every other test goes to whichever worker is free. The long ones (live, browser, slow) are handed out
first, so that the session ends on short tests rather than with one worker idle beside a minute-long run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_FIXTURES = (
    "tests/perception/",  # the session's model, clips and pipeline runs (tests/perception/conftest.py)
    "tests/services/test_face_video_live.py",  # one face-video run (about 100 s) read by several tests
    "tests/services/test_logs_independent.py",
    "tests/services/test_live.py",
    "tests/security/test_forge.py",
    "tests/security/test_access_control.py",
    "tests/console/test_replay.py",
)


def pytest_itemcollected(item: pytest.Item) -> None:
    """Marks as it is collected, before any plugin's collection_modifyitems (xdist reads the groups there)."""
    path = item.path.relative_to(ROOT).as_posix()
    group = next((prefix for prefix in SHARED_FIXTURES if path.startswith(prefix)), None)
    if group is not None:
        item.add_marker(pytest.mark.xdist_group(group))


LONG = ("live", "browser", "slow")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Long tests first (a stable sort: within each kind, the collection order)."""
    items.sort(key=lambda item: not any(item.get_closest_marker(mark) for mark in LONG))
