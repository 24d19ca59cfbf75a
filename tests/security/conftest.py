"""Every security test must leave no child process behind (the router and recorder included)."""

from __future__ import annotations

import psutil
import pytest


def live_children() -> list[psutil.Process]:
    out = []
    for p in psutil.Process().children(recursive=True):
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.Error:
            pass
    return out


@pytest.fixture(autouse=True)
def no_process_left_behind():
    before = {p.pid for p in live_children()}
    yield
    left = [p for p in live_children() if p.pid not in before]
    described = []
    for p in left:
        try:
            described.append((p.pid, p.cmdline()))
            p.kill()
        except psutil.Error:
            pass
    assert not left, f"processes left behind: {described}"
