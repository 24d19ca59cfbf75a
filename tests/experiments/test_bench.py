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
    proc = subprocess.run([sys.executable, "-m", "experiments", "reproduce", "--only", "nonexistent"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "experiments", "bench", "--trials", "0"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "must be positive" in proc.stderr
