"""`python -m experiments bench-compare --what live`: both checkouts' runs are found and compared, whatever
directory it is run from (each checkout's bench runs in its own directory, so a relative `--out` must not be read
as theirs)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.services.live import ROOT, env

pytestmark = pytest.mark.live


def test_bench_compare_from_another_directory_with_a_relative_out(tmp_path):
    other = tmp_path / "other"
    subprocess.run(
        ["git", "worktree", "add", "--detach", str(other), "HEAD"], cwd=ROOT, check=True, capture_output=True
    )
    try:
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "experiments",
                "bench-compare",
                "--what",
                "live",
                "--against",
                str(other),
                "--phases",
                "ingest",
                "--steps",
                "100",
                "--rounds",
                "1",
                "--out",
                "compared",
            ],
            cwd=tmp_path,
            env=env(),
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT, capture_output=True)
    assert done.returncode == 0, done.stdout + done.stderr
    (result,) = (tmp_path / "compared").glob("*/compare.json")
    rows = json.loads(result.read_text())["rows"]["ingest"]
    assert rows["this"][0] > 0 and rows["other"][0] > 0, rows
