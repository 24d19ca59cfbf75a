"""The bench's `paced` phase: what the live system costs while a person teaches at their own pace.

A run of `python -m services up --teacher web` at `rate` steps/s is taught by the scripted person
(`static/scripted_person.js`, the paper's rule) in Debian's Chromium through Playwright, the way
`python -m services.console scripted` does. After `warmup` s (start-up: imports, the first connections,
the page's clock burst), the CPU time of every process is read from /proc/PID/stat (utime + stime) every
second for `seconds` s; a process's share of one core is the CPU time it used in that window over the
window's wall time. Services are named by their module (`python -m services.NAME`; the launcher's own
process also runs the embedded router), the browser's processes by Chromium's `--type` (the browser
process itself is `browser`), and Playwright's driver apart from both.

With `checkouts`, the same phase then runs on each other checkout of the project (its own `services up`, its
own page and JavaScript), so figures of two versions come from one command on one machine.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
TICK = os.sysconf("SC_CLK_TCK")
URL = re.compile(r"console: (http://127\.0\.0\.1:\d+/[#?]token=[A-Za-z0-9_.-]+)")  # (older: ?token=)


@dataclass(frozen=True)
class PacedSettings:
    """What the paced phase runs (from the bench's flags)."""

    seconds: float
    warmup: float
    rate: float
    env: str
    algo: str
    out: Path
    press_p: float = 0.5


def read_cpu(pid: int) -> tuple[int, float] | None:
    """(parent pid, utime + stime in s) of a process from /proc/PID/stat; None once it is gone."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = raw[raw.rindex(")") + 2 :].split()  # after "pid (comm) ": the name may hold spaces
    return int(fields[1]), (int(fields[11]) + int(fields[12])) / TICK


def read_cmdline(pid: int) -> list[str]:
    """A process's arguments (Chromium's helpers rewrite theirs into one string: split on spaces too)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").replace("\0", " ").split()
    except OSError:
        return []


def descendants(root: int) -> dict[int, float]:
    """pid -> CPU seconds of `root` and every process below it."""
    table = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (got := read_cpu(int(entry))) is not None:
            table[int(entry)] = got
    keep, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        kids = [pid for pid, (ppid, _) in table.items() if ppid == parent and pid not in keep]
        keep.update(kids)
        frontier += kids
    return {pid: table[pid][1] for pid in keep if pid in table}


def label(pid: int, service_root: int) -> str:
    """What a process is: `service:NAME`, `browser:TYPE` or `playwright-driver`."""
    cmd = read_cmdline(pid)
    if pid == service_root:
        return "service:launcher+router"
    if "-m" in cmd and cmd.index("-m") + 1 < len(cmd) and cmd[cmd.index("-m") + 1].startswith("services."):
        return "service:" + cmd[cmd.index("-m") + 1].split(".")[1]
    if cmd and "chrom" in os.path.basename(cmd[0]):
        kind = next((a.split("=", 1)[1] for a in cmd if a.startswith("--type=")), "browser")
        return f"browser:{kind}"
    return "playwright-driver" if any("playwright" in a or "node" in a for a in cmd[:2]) else "other"


class CpuWatch:
    """CPU seconds of every process of a run and of its browser, read every second; the last value of a process
    that exits is kept, one that appears counts from zero."""

    def __init__(self, service_root: int, browser_root: int):
        self.roots = (service_root, browser_root)
        self.first: dict[int, float] = {}
        self.last: dict[int, float] = {}
        self.names: dict[int, str] = {}

    def sample(self, first: bool = False) -> None:
        for root in self.roots:
            for pid, cpu in descendants(root).items():
                if pid == os.getpid():
                    continue
                if pid not in self.names:
                    self.names[pid] = label(pid, self.roots[0])
                    self.first[pid] = cpu if first else 0.0
                self.last[pid] = cpu

    def shares(self, wall: float) -> dict[str, float]:
        """Percent of one core per label over `wall` seconds."""
        out: dict[str, float] = {}
        for pid, name in self.names.items():
            out[name] = out.get(name, 0.0) + (self.last[pid] - self.first[pid])
        return {k: round(100 * v / wall, 2) for k, v in sorted(out.items())}


def start_run(checkout: Path, s: PacedSettings, run: str) -> tuple[subprocess.Popen, list[str]]:
    cmd = [
        sys.executable,
        "-m",
        "services",
        "up",
        "--teacher",
        "web",
        "--env",
        s.env,
        "--algo",
        s.algo,
        "--rate",
        str(s.rate),
        "--episodes",
        "100000",
        "--out",
        str(s.out),
        "--run",
        run,
        "--progress",
        "false",
    ]
    env = {**os.environ, "PYTHONPATH": str(checkout), "PYTHONUNBUFFERED": "1"}
    up = subprocess.Popen(
        cmd, cwd=checkout, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
    )
    lines: list[str] = []
    out = up.stdout
    assert out is not None  # (stdout=PIPE)
    threading.Thread(target=lambda: lines.extend(out), daemon=True).start()
    return up, lines


def console_url(up: subprocess.Popen, lines: list[str], timeout: float = 300.0) -> str:
    t0 = time.monotonic()
    while up.poll() is None and time.monotonic() - t0 < timeout:  # a loaded machine starts slowly
        if m := URL.search("".join(lines)):
            return m.group(1)
        time.sleep(0.2)
    raise RuntimeError("services up printed no console address:\n" + "".join(lines)[-2000:])


def measure(page: Any, up: subprocess.Popen, s: PacedSettings) -> dict[str, Any]:
    """Wait out start-up, then read CPU times each second for `seconds` s; the steps shown in that window."""
    time.sleep(s.warmup)
    browser_root = os.getpid()  # Playwright's driver and Chromium are this process's children
    watch = CpuWatch(up.pid, browser_root)
    seq0, t0 = page.evaluate("hitl.step ? hitl.step.seq : -1"), time.monotonic()
    watch.sample(first=True)
    while time.monotonic() - t0 < s.seconds and up.poll() is None:
        time.sleep(1.0)
        watch.sample()
    wall = time.monotonic() - t0
    if up.poll() is not None:  # the run ended inside the window: its figures are not a paced run's
        raise RuntimeError(f"services up exited with code {up.returncode} {wall:.1f} s into the measured window")
    seq1 = page.evaluate("hitl.step ? hitl.step.seq : -1")
    presses = page.evaluate("(window.hitlScriptedPlan || []).length")
    return {"wall_s": round(wall, 2), "steps": seq1 - seq0, "presses": presses, "cpu_pct": watch.shares(wall)}


def paced_once(checkout: Path, s: PacedSettings, run: str) -> dict[str, Any]:
    """One paced run on `checkout`, measured; the run is ended from the page afterwards."""
    from playwright.sync_api import sync_playwright

    from services.console.scripted import CHROMIUM, FLAGS, STATIC

    up, lines = start_run(checkout, s, run)
    try:
        url = console_url(up, lines)
        with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
            ctx = pw.chromium.launch_persistent_context(
                profile, executable_path=CHROMIUM, headless=True, args=list(FLAGS)
            )
            page = ctx.new_page()
            page.goto(url)
            page.wait_for_function("window.hitl && hitl.hello && hitl.clock.ready", timeout=120_000)
            page.add_script_tag(path=str(STATIC / "scripted_person.js"))
            page.evaluate("o => { hitlScriptedPerson(o); }", {"p": s.press_p, "lagMin": 0.3, "lagMax": 1.5, "seed": 1})
            result = measure(page, up, s)
            page.on("dialog", lambda d: d.accept())
            page.click("#end")
            result["exit_code"] = up.wait(120)
            ctx.close()
    finally:
        if up.poll() is None:
            os.killpg(up.pid, 15)
            up.wait(30)
    result.update(run_summary(s.out / run))
    return result


def run_summary(rundir: Path) -> dict[str, Any]:
    """Zero loss from the run's summary: every step sent is logged and learned, every press logged."""
    try:
        sm = json.loads((rundir / "summary.json").read_text())
    except (OSError, ValueError) as exc:
        return {"zero_loss": False, "summary_error": str(exc)}
    n = sm.get("steps_sent")
    ok = bool(n) and sm.get("steps_logged") == n and sm.get("steps_learned") == n
    return {
        "zero_loss": ok and sm.get("feedback_logged") == sm.get("feedback_sent"),
        "steps_sent": n,
        "feedback_sent": sm.get("feedback_sent"),
        "outcome": sm.get("outcome"),
    }


def totals(r: dict[str, Any]) -> dict[str, float]:
    pct = r["cpu_pct"]
    svc = sum(v for k, v in pct.items() if k.startswith("service:"))
    web = sum(v for k, v in pct.items() if k.startswith("browser:"))
    per_step = 10 * svc * r["wall_s"] / max(r["steps"], 1)  # % of a core over wall s -> ms
    return {"services": round(svc, 2), "browser": round(web, 2), "services_cpu_ms_per_step": round(per_step, 2)}


def paced_phase(s: PacedSettings, checkouts: tuple[str, ...], stamp: str) -> dict[str, Any]:
    """The phase on this checkout, then on each of `checkouts`; each result with its totals."""
    out = {}
    for i, co in enumerate((str(ROOT), *checkouts)):
        print(
            f"-- paced on {co}: {s.warmup:g} s start-up, then {s.seconds:g} s measured --", file=sys.stderr, flush=True
        )
        r = paced_once(Path(co).resolve(), s, f"bench-{stamp}-paced-{i}")
        r["totals"] = totals(r)
        out[co] = r
        print(format_paced({co: r}), file=sys.stderr, flush=True)
    return out


def format_paced(res: dict[str, Any]) -> str:
    lines = []
    base = None
    for co, r in res.items():
        t = r["totals"]
        lines.append(
            f"paced on {co}: {r['steps']} steps and {r['presses']} presses in {r['wall_s']} s, zero loss: "
            f"{'yes' if r['zero_loss'] else 'NO'}; % of one core: services {t['services']:.2f} "
            f"({t['services_cpu_ms_per_step']:.1f} ms CPU per step), browser {t['browser']:.2f}"
        )
        lines.append("  " + ", ".join(f"{k} {v:.2f}" for k, v in r["cpu_pct"].items()))
        if base is not None:  # this checkout (the first) over that one: below 1 is cheaper here
            ratios = {k: f"{base[k] / t[k]:.2f}" if t[k] else "n/a" for k in ("services", "browser")}
            lines.append(
                f"  ratio {next(iter(res))} / {co}: services {ratios['services']}, browser {ratios['browser']}"
            )
        base = base or t
    return "\n".join(lines)
