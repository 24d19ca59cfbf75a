"""The per-trial table: reproduce writes it, `report --from` recomputes the same claims.json from it alone,
and the committed table reproduces the committed docs/results/claims.json exactly."""

import json
import lzma
import os
import time

from experiments import reproduce as rep
from experiments.__main__ import main
from experiments.conditions import BY_NAME, Scale
import hashlib

import numpy as np

from experiments import trials
from experiments.conditions import n_trials
from experiments.trials import COLUMNS, read_table, table_bytes, table_parts, write_table

TINY = Scale(
    layouts=4,
    reps=1,
    maze_episodes=3,
    taxi_episodes=2,
    taxi_random_episodes=2,
    taxi_trials=2,
    first_layout=0,
    seed_block=1,
)
RESULTS = os.path.join(os.path.dirname(__file__), "..", "..", "docs", "results")


def test_report_from_the_table_recomputes_claims_exactly_without_running_a_trial(tmp_path, monkeypatch):
    conds = [BY_NAME[n] for n in ("maze-flip", "maze-high-delay")]
    run = tmp_path / "run"
    rep.reproduce(conds, TINY, str(run), workers=1, progress=False, n_boot=50, argv=["reproduce", "--test"])
    with lzma.open(run / "trials.csv.xz", "rt") as fh:
        header = fh.readline().strip().split(",")
        rows = sum(1 for _ in fh)
    assert tuple(header) == COLUMNS and rows == (4 + 7) * 4 * 3  # arms x trials x episodes
    table = read_table(str(run / "trials.csv.xz"))
    assert list(table.data) == ["maze-flip", "maze-high-delay"]
    assert list(table.data["maze-high-delay"]) == list(BY_NAME["maze-high-delay"].arms)

    def no_trials(*a, **k):
        raise AssertionError("report --from ran a trial")

    monkeypatch.setattr("experiments.runner.run_trials", no_trials)
    out = tmp_path / "again"
    assert main(["report", "--from", str(run / "trials.csv.xz"), "--out", str(out), "--n-boot", "50"]) == 0
    assert json.loads((out / "claims.json").read_text()) == json.loads((run / "claims.json").read_text())
    assert (out / "maze-flip.png").stat().st_size > 5000 and "| C6 | **" in (out / "REPORT.md").read_text()
    assert "4 layouts (0-3), 2 honest" in (out / "REPORT.md").read_text()  # the run's own layouts


def test_a_malformed_table_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "trials.csv.xz"
    with lzma.open(bad, "wt") as fh:
        fh.write("condition,arm\nmaze-flip,dqn\n")
    (tmp_path / "timing.json").write_text(json.dumps({"scale": TINY.__dict__}))
    assert main(["report", "--from", str(bad), "--out", str(tmp_path / "out")]) == 1
    assert "not a trials table" in capsys.readouterr().err


def test_the_committed_table_reproduces_the_committed_claims(tmp_path):
    """docs/results/claims.json says which table it was computed from; recomputing from that table alone
    gives it exactly. (A report from before the table existed, the 23 November declaration's, names none:
    then it must be that report, with no M1.)"""
    with open(os.path.join(RESULTS, "claims.json")) as fh:
        committed = json.load(fh)
    if "table" not in committed:
        assert "M1" not in committed["claims"] and not os.path.exists(os.path.join(RESULTS, "trials.csv.xz"))
        return
    table = os.path.join(RESULTS, committed["table"]["file"])
    assert len(table_bytes(table)) < 8 * 2**20  # a few MB at most
    t0 = time.perf_counter()
    assert main(["report", "--from", table, "--out", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "claims.json").read_text()) == committed
    assert "M1" in committed["claims"]
    print(f"recomputed in {time.perf_counter() - t0:.1f} s")


def test_a_table_past_the_file_limit_is_written_in_pieces_that_read_back_the_same(tmp_path, monkeypatch):
    """A table whose xz stream passes PART_BYTES goes out as pieces; joined they are the whole file's bytes, and
    read_table gives the same arrays from either form (report --from names trials.csv.xz in both cases)."""
    cond = BY_NAME["maze-flip"]
    rng = np.random.default_rng(0)
    records = {
        (cond.name, arm, k): {
            "spec": {"layout": k, "seed": 100 + k},
            "steps": rng.integers(5, 300, 3),
            "return": rng.normal(size=3),
        }
        for arm in cond.arms
        for k in range(n_trials(cond, TINY))
    }
    whole, split = tmp_path / "whole" / "trials.csv.xz", tmp_path / "split" / "trials.csv.xz"
    whole.parent.mkdir(), split.parent.mkdir()
    rows = write_table(str(whole), [cond], TINY, records)
    assert rows == len(cond.arms) * 4 * 3 and not table_parts(whole)
    monkeypatch.setattr(trials, "PART_BYTES", 300)
    assert write_table(str(split), [cond], TINY, records) == rows
    parts = table_parts(split)
    assert not split.exists() and len(parts) >= 2 and all(p.stat().st_size <= 300 for p in parts)
    assert [p.name for p in parts][:2] == ["trials.csv.xz.part-001", "trials.csv.xz.part-002"]
    assert hashlib.sha256(table_bytes(str(split))).digest() == hashlib.sha256(whole.read_bytes()).digest()
    a, b = read_table(str(whole)), read_table(str(split))
    for arm in cond.arms:
        assert np.array_equal(a.data[cond.name][arm].steps, b.data[cond.name][arm].steps)
        assert np.array_equal(a.data[cond.name][arm].returns, b.data[cond.name][arm].returns)
    monkeypatch.setattr(trials, "PART_BYTES", 10**9)  # written whole again: the pieces go
    write_table(str(split), [cond], TINY, records)
    assert split.exists() and not table_parts(split)
