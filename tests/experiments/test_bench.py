"""The benchmark command: three ways of running the same trials, identical results, ratios reported."""

import json
import subprocess
import sys

from experiments.bench import bench, format_report


def test_bench_runs_the_same_trials_three_ways_and_reports_ratios(tmp_path):
    out = tmp_path / "bench.json"
    report = bench(["maze-high-delay", "pomdp-stop"], trials=1, episodes=2, workers=2, out=str(out))
    assert report["trials"] == 8 and report["env_steps"] > 0
    for key in ("plain_s", "batched_s", "parallel_s", "speedup_batched", "speedup_parallel"):
        assert report[key] > 0
    assert json.loads(out.read_text())["trials"] == 8
    text = format_report(report)
    assert "plain loop" in text and "speed-up x" in text


def test_cli_wiring(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments", "reproduce", "--only", "nonexistent"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    proc = subprocess.run(
        [sys.executable, "-m", "experiments", "bench", "--trials", "0"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2 and "must be positive" in proc.stderr
    # Parsing a command line loads no heavy library (they took 4.5 s of every command's start, errors included)
    heavy = ("torch", "scipy.stats", "matplotlib.pyplot")
    probe = "import sys; from experiments.__main__ import commands; commands(); "
    probe += f"print([m for m in {heavy} if m in sys.modules])"
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert loaded.stdout.strip() == "[]", loaded.stdout


def test_bench_compare_alternates_two_checkouts_and_prints_ratios(tmp_path):
    """Against itself (the same checkout twice): every round prints both modes, the median is printed and
    written; a directory that is not a checkout is a one-line error."""
    from experiments.bench_compare import ROOT

    out = tmp_path / "compare.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments",
            "bench-compare",
            "--against",
            str(ROOT),
            "--rounds",
            "2",
            "--envs",
            "maze",
            "--episodes",
            "1",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("plain") >= 2 and "median ratio this/other" in proc.stdout
    result = json.loads(out.read_text())
    assert len(result["runs"]) == 2 and set(result["medians"]) == {"plain_s", "batched_s"}
    assert result["runs"][0]["this"]["env_steps"] == result["runs"][0]["other"]["env_steps"] > 0
    # one maze batch of the four agents, one episode each: its ticks are its longest trial's steps
    first = result["runs"][0]["this"]
    assert 0 < first["ticks"] <= first["env_steps"] and len(result["tick_ratios"]) == 2
    assert "lockstep ticks per second" in proc.stdout
    proc = subprocess.run(
        [sys.executable, "-m", "experiments", "bench-compare", "--against", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert proc.returncode == 2 and "not a checkout of this project" in proc.stderr
