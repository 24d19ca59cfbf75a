"""Every plumbing test must leave no child process behind."""

from __future__ import annotations

import psutil
import pytest


@pytest.fixture(autouse=True)
def no_process_left_behind():
    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    yield
    left = [
        p
        for p in me.children(recursive=True)
        if p.pid not in before and p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    ]
    described = []
    for p in left:
        try:
            described.append((p.pid, p.cmdline()))
            p.kill()
        except psutil.Error:
            pass
    assert not left, f"processes left behind: {described}"
