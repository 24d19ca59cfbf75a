"""The same sweep through a real local Ray head (127.0.0.1, two CPUs) gives the local pool's results, and
leaves no Ray process behind."""

import json
import os
import subprocess
import sys

import psutil

from experiments.__main__ import main
from experiments.sweeps.ray_head import local_head

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SWEEP = [
    "sweep",
    "--grid",
    "agent.algo=dqn,dqn-tamer",
    "--set",
    "episodes=3",
    "observer.p_feedback=0.3",
    "--trials",
    "4",
    "--no-progress",
    "--boot",
    "50",
    "--contrast",
    "agent.algo=dqn-tamer - agent.algo=dqn",
]
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "PYTHONPATH": ROOT}


def run(args, timeout=300):
    res = subprocess.run(
        [sys.executable, "-m", "experiments", *args], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return res.stdout


def test_a_sweep_through_a_local_ray_head_equals_the_local_pool(tmp_path):
    with local_head(num_cpus=2) as head:
        assert main([*SWEEP, "--out", str(tmp_path / "local"), "--workers", "1"]) == 0  # local, in this process
        remote = run([*SWEEP, "--out", str(tmp_path / "ray"), "--ray", head.address])
        head.snapshot()
        assert "computed on ray" in remote
        # the Ray run's results were streamed back into its own cache: a repeat computes nothing
        assert "nothing to compute" in run([*SWEEP, "--out", str(tmp_path / "ray"), "--ray", head.address])
        # the reproduction is the same engine: its named grid runs through the head too
        run(
            [
                "reproduce",
                "--only",
                "maze-high-nodelay",
                "--layouts",
                "4",
                "--maze-episodes",
                "3",
                "--no-progress",
                "--out",
                str(tmp_path / "paper"),
                "--ray",
                head.address,
            ]
        )
        head.snapshot()
        timing = json.loads((tmp_path / "paper" / "timing.json").read_text())
        assert timing["ray"] == head.address and timing["trials_computed"] > 0 and timing["jobs"]
        assert len(head.seen) >= 3  # gcs, raylet, workers...: the check below is not vacuous
    for name in ("trials.csv", "summary.csv", "contrasts.json"):
        assert (tmp_path / "ray" / name).read_text() == (tmp_path / "local" / name).read_text(), name
    cached = sorted(p.relative_to(tmp_path / "ray") for p in (tmp_path / "ray" / "cache").rglob("*.json"))
    assert cached == sorted(p.relative_to(tmp_path / "local") for p in (tmp_path / "local" / "cache").rglob("*.json"))
    assert head.left == [], f"Ray processes left behind (killed): {head.left}"
    alive = [p for p in head.seen.values() if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    assert alive == []
    assert not any(head.temp in " ".join(p.info["cmdline"] or []) for p in psutil.process_iter(["cmdline"]))
