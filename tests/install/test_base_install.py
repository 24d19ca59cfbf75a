"""The base install alone (`pip install .`, no extras) runs the live system with the oracle teacher.

How: every Python process of the run (the launcher and each service it starts) loads site/sitecustomize.py, which
makes the modules of every installed distribution outside the base install's closure raise ImportError, as if
they were not installed (base_only.py computes that closure from pyproject.toml and the installed metadata). A
fresh venv would test the same within the minute only from a prepared wheel cache, and one with
--system-site-packages would see everything; this checks the same imports on the real services in ~15 s.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from subprocess import PIPE, STDOUT

import pytest

from tests.install.base_only import ROOT, SITE, blocked_modules
from tests.services.live import kill_tree

pytestmark = pytest.mark.live
# The heavy optional dependencies the issue names, and the extras' own modules: none may be in the base install.
OPTIONAL = ("cv2", "onnx", "onnxruntime", "h5py", "matplotlib", "pyarrow", "foxglove", "aiohttp", "ray", "pytest")


def base_only_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SITE), str(ROOT)])
    env["BASE_ONLY_BLOCKED"] = ",".join(blocked_modules())
    return env


def test_optional_dependencies_are_outside_the_base_install_and_blocked():
    blocked = set(blocked_modules())
    assert set(OPTIONAL) <= blocked, f"in the base install: {sorted(set(OPTIONAL) - blocked)}"
    probe = (
        "import importlib, sys\nfor m in sys.argv[1:]:\n    try:\n        importlib.import_module(m)\n"
        "    except ImportError:\n        continue\n    print('imported', m)\nimport numpy, torch, zenoh, mcap"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe, *OPTIONAL], env=base_only_env(), capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0 and "imported" not in out.stdout, out.stdout + out.stderr


def test_base_install_runs_actor_learner_and_oracle_teacher(tmp_path):
    args = "up --env maze --algo dqn-tamer --teacher oracle --episodes 2 --run base --progress false".split()
    cmd = [sys.executable, "-m", "services", *args, "--out", str(tmp_path)]
    env = base_only_env()
    popen = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=PIPE, stderr=STDOUT, text=True, start_new_session=True)
    try:
        out, _ = popen.communicate(timeout=120)
    finally:
        kill_tree(popen.pid)
    assert popen.returncode == 0, out
    summary = json.loads((tmp_path / "base" / "summary.json").read_text())
    assert summary["outcome"] == "ok" and "summary_error" not in summary, summary
    assert len(summary["returns"]) == 2, summary
    assert summary["steps_seq_contiguous_in_log"] and summary["steps_learned"] == summary["steps_sent"] > 0, summary
    assert summary["feedback_credited"] > 0 and summary["weights_logged"] > 0, summary
    assert "no learning_curve.png: matplotlib is not installed" in out, out
    assert not (tmp_path / "base" / "learning_curve.png").exists()
    logs = {p.name: p.read_text() for p in (tmp_path / "base" / "logs").glob("*.log")}
    assert {"actor.log", "learner.log", "recorder.log"} <= set(logs) and any("oracle" in n for n in logs), logs
    assert not [n for n, text in logs.items() if "Traceback" in text], logs


def test_a_log_recorded_with_every_extra_reads_in_the_base_install(tmp_path):
    """The full install's recorder draws the scene (foxglove-sdk) into the log; the base install's replay skips it."""
    args = "up --env maze --algo dqn-tamer --teacher oracle --episodes 2 --run full --progress false".split()
    cmd = [sys.executable, "-m", "services", *args, "--out", str(tmp_path)]
    full_env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(cmd, cwd=ROOT, env=full_env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    full = json.loads((tmp_path / "full" / "summary.json").read_text())
    log = str(tmp_path / "full" / "session.mcap")
    cmd = [sys.executable, "-m", "services.replay", log, "summary", "--json", "--no-plot"]
    out = subprocess.run(cmd, cwd=ROOT, env=base_only_env(), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    base = json.loads(out.stdout)
    assert base["steps_logged"] == full["steps_logged"] > 0 and base["returns"] == full["returns"], out.stderr
    assert base["log"]["messages"] == full["log"]["messages"]


@pytest.mark.parametrize(
    ("args", "extra"),
    [("--teacher web", "console"), ("--teacher face-video", "perception"), ("--foxglove 8766", "foxglove")],
)
def test_a_part_outside_the_base_install_names_its_extra(tmp_path, args, extra):
    cmd = [sys.executable, "-m", "services", "up", *args.split(), "--episodes", "1", "--out", str(tmp_path)]
    out = subprocess.run(cmd, cwd=ROOT, env=base_only_env(), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and f"pip install 'hitl-tamer[{extra}]'" in out.stderr, out.stdout + out.stderr
    assert "Traceback" not in out.stderr and not list(tmp_path.iterdir())
