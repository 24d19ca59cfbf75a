"""The paced bench's CPU accounting (services/bench_paced.py) on real processes: /proc's times, the process tree,
the labels. The figures themselves come from `python -m services bench --phases paced`, never from a test."""

import contextlib
import os
import signal
import subprocess
import sys
import time

from services.bench_paced import CpuWatch, descendants, format_paced, label, read_cpu, totals

BURN = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.6: pass\ntime.sleep(30)"


def test_cpu_watch_counts_a_busy_child_and_not_an_idle_one():
    busy = subprocess.Popen([sys.executable, "-c", BURN])
    idle = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        time.sleep(0.3)  # both started (their start-up is counted from the first sample on)
        watch = CpuWatch(service_root=busy.pid, browser_root=idle.pid)
        watch.sample(first=True)
        t0 = time.monotonic()
        while watch.last[busy.pid] - watch.first[busy.pid] < 0.3 and time.monotonic() - t0 < 30:
            time.sleep(0.2)  # (a loaded machine gives the busy one its CPU later)
            watch.sample()
        assert set(watch.names) == {busy.pid, idle.pid}
        used = {pid: watch.last[pid] - watch.first[pid] for pid in watch.names}
        assert used[busy.pid] >= 0.3 > 0.1 > used[idle.pid]
        shares = watch.shares(time.monotonic() - t0)
        assert list(shares) == ["other", "service:launcher+router"]  # the root of the services is the launcher
        assert shares["service:launcher+router"] > shares["other"]
    finally:
        for p in (busy, idle):
            p.kill()
            p.wait()


def test_descendants_follow_the_tree_and_a_gone_process_reads_as_none():
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import subprocess, sys, time; "
            "c = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)']); "
            "print(c.pid, flush=True); time.sleep(30)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert parent.stdout is not None  # (stdout=PIPE)
    child = int(parent.stdout.readline())
    try:
        assert set(descendants(parent.pid)) == {parent.pid, child}
        got = read_cpu(child)
        assert got is not None and got[0] == parent.pid  # (parent pid, CPU seconds)
        assert label(child, parent.pid) == "other" and label(parent.pid, parent.pid) == "service:launcher+router"
    finally:
        parent.kill()
        parent.wait()
        with contextlib.suppress(ProcessLookupError):
            os.kill(child, signal.SIGKILL)
    time.sleep(0.2)
    assert read_cpu(parent.pid) is None


def test_report_sums_services_and_browser_and_gives_the_ratio():
    def result(svc: float, web: float) -> dict:
        pct = {"service:actor": svc / 2, "service:learner": svc / 2, "browser:renderer": web, "playwright-driver": 9.0}
        return {"steps": 120, "presses": 60, "wall_s": 60.0, "zero_loss": True, "cpu_pct": pct}

    new, old = result(2.0, 4.0), result(8.0, 16.0)
    for r in (new, old):
        r["totals"] = totals(r)
    assert new["totals"] == {"services": 2.0, "browser": 4.0, "services_cpu_ms_per_step": 10.0}
    text = format_paced({"new": new, "old": old})
    assert "ratio new / old: services 0.25, browser 0.25" in text
